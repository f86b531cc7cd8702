"""`avatarkit face`: what the face front end sees in one photo."""
from __future__ import annotations

import click

from avatarkit.cli.options import quiet_option


@click.command("face")
@click.argument("image", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Overlay image to write (.png, .jpg).")
@click.option("--face-index", type=click.IntRange(min=0), help="Which face to fit (left to right from 0; "
              "default the largest).")
@click.option("--fit/--no-fit", default=True, show_default=True,
              help="Fit the head model's landmarks to the chosen face and draw them (red crosses).")
@click.option("--head-model", type=click.Path(dir_okay=False), help="FLAME model instead of the template "
              "(needs --landmark-embedding).")
@click.option("--landmark-embedding", type=click.Path(dir_okay=False),
              help="FLAME's mediapipe_landmark_embedding.npz for --head-model.")
@quiet_option
def face_cmd(image, output, face_index, fit, head_model, landmark_embedding, quiet):
    """Draw what the face front end sees in IMAGE: MediaPipe's face boxes and keypoints (yellow,
    magenta), the 468-point face mesh (green), outline and lips (white), irises (cyan) and the
    fitted head's landmarks (red).

    \b
    Example:
      avatarkit face samples/portrait.jpg -o overlay.png
    """
    import json

    from avatarkit.face.correspondence import read_embedding
    from avatarkit.face.overlay import draw_overlay, look_at_faces
    from avatarkit.head.io import load_head_model
    from avatarkit.recon.image_io import read_image, write_image

    rgb = read_image(image)
    model = load_head_model(head_model)
    emb = read_embedding(landmark_embedding, model.num_faces) if landmark_embedding else None
    look = look_at_faces(rgb, face_index, fit, model, emb, path=image)
    write_image(output, draw_overlay(rgb, look))
    if not quiet:
        click.echo(json.dumps(look.summary), err=True)
        click.echo(f"wrote {output}: {len(look.faces)} face(s)", err=True)
