"""Several calibrated views of the rest avatar (a video build's keyframes): cameras, visibility,
multi-view colour, hair label votes and the silhouette bound on the hair.

Cameras. The keyframes' head poses come from the joint identity fit (`track.joint_identity`) in
`face.fit`'s view frame (X_view = M_k X_head, camera at the origin). The portrait build fits the
reference keyframe again (`recon.fit`, with landmarks, face width and silhouette) and the
avatar lives in that fit's head frame, M_b. With M_r the joint fit's pose of the same reference
frame, keyframe k sees the avatar's rest frame through
    X_view_k = M_k M_r^-1 M_b X_avatar
so every keyframe is registered to the build's own reference camera (`keyframe_cameras`). The
head is treated as rigid: keyframes are chosen with a neutral mouth (`track.keyframes`). A
keyframe may carry a second pose for the bald layer (`Keyframe.skin_pose`, `VideoViews.skin_views`):
the bald discs' colours and outline are then the skin's pose's, the hair's everything the pose's.

Visibility (`view_samples`, with `recon.visibility.seen_from`): the union of bald and hair
Gaussians is rendered from the keyframe's
camera; a Gaussian is seen when its centre projects inside the image onto a pixel with alpha >
`ALPHA_MIN`, labelled skin or hair in that keyframe's segmentation at least `EDGE_MARGIN` of
the image away from any other label (a pose a few pixels off would otherwise sample the
background or the clothes at the silhouette), and its camera depth is at
most the rendered depth there + `DEPTH_TOLERANCE` (the render's depth is the alpha-weighted
expected depth of the front surface). A seen Gaussian's sample is the keyframe image at its
projection (bilinear); its weight is cos(angle between the surface normal and the direction to
the camera)^2 x the keyframe's sharpness, zero below `MIN_COS` (grazing views smear).
Normals are the head SDF's gradient at the Gaussian: the bald head's surface normal. Hair has
no surface normal to face (the shell's outward direction says little about a strand seen from
the side): a hair Gaussian is seen when the renderer shows at least `HAIR_VISIBLE` of its own
footprint inside the person (`footprint_visibility`: its blending weight alpha T summed over
the pixels of the person mask, over its unoccluded integral), and that share is its weight (x
sharpness; with `HAIR_FACING` (on), also weighed down where the view looks along the hair shell). Every sample's weight is then multiplied by `person_weight`: the soft person mask
(`soft_person`: the segmentation's person mask without the background-coloured halo a
segmentation can take in at the silhouette, blurred) mapped so that a pixel on the silhouette,
half background, gives nothing.

Colour (`blend_colours`): each Gaussian's colour = the weighted mean of its samples over the
keyframes, the reference view's weight multiplied by `REFERENCE_WEIGHT` (the portrait build's
colours, matched to the reference photo afterwards, keep priority on the face); a Gaussian no
keyframe saw keeps the portrait build's colour (its fill), except hidden hair: hair no keyframe
saw takes the mean colour of the `HAIR_NEIGHBOURS` nearest hair Gaussians a keyframe did see
(the back of the head is the colour of the hair around it; the single view's fill there is
whatever the photo showed in front of it), and the hidden scalp: bald Gaussians of the scalp no
keyframe saw, where the reference view looks away from them, take the mean colour of the
nearest scalp Gaussians a keyframe did see (`SCALP_FILL`). Hair the reference view shows edge-on
that the other keyframes see on skin-labelled pixels may be dropped (`EDGE_HAIR_ON_SKIN`, off; not
in the registration drafts). Gaussians of the bald head bound to the neck that
the reference view shows are left alone (the tracked head turns, the neck and the clothes below
it need not); the neck's sides and back, which the photo does not show, take the blend
(`NECK_SHOWN`; None: the whole neck is left alone), and what of them no keyframe saw may take
the colour of the nearest neck that has one (`NECK_FILL`, on since session 27).

Hair labels: `recon.pipeline.clean_hair` with every keyframe's camera and label image (the label
lifting sums the votes of all views; with `recon.hair_reassign.CLEAR_SHARE` (off) a candidate of
the boundary-aware reassignment that the views see as skin or body clear of every hair edge
leaves the hair whatever its looks, in the final build only, `VideoViews.clears_hair`). Silhouette bound (`silhouette_outside`): a hair Gaussian
whose centre projects inside a keyframe's image but outside that keyframe's person mask
(`soft_person` >= 0.5, dilated by `SILHOUETTE_MARGIN` of the image's longer side to
absorb the poses' error) is outside the visual hull and is removed. The mask is first joined
with the fitted head mesh seen by that keyframe (`head_silhouette`, eroded by the same
margin): the person's silhouette holds the head, so a keyframe whose segmentation has a hole
there removes nothing through it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avatarkit.render.camera import Camera

#: a pixel with less rendered alpha shows no surface
ALPHA_MIN = 0.5
#: metres a Gaussian may lie behind the rendered depth and still count as seen
DEPTH_TOLERANCE = 0.008
#: views at a grazing angle (cos below this) give no sample
MIN_COS = 0.35
#: samples only this far (share of the image's longer side) inside the skin + hair region
EDGE_MARGIN = 0.015
#: hidden hair takes the mean colour of this many nearest seen hair Gaussians
HAIR_NEIGHBOURS = 8
#: a sample's weight is cos(view angle) to this power (x sharpness)
COS_POWER = 2
#: the reference keyframe's weight factor (the portrait build's view)
REFERENCE_WEIGHT = 3.0
#: a hair Gaussian's sample is weighted, besides its visibility, by min(1, max(cos /
#: HAIR_FACING, `HAIR_FACING_FLOOR`)) ^ `COS_POWER`, cos between the head's outward normal at it
#: (the SDF's gradient, as for the bald layer) and the direction to the camera
#: (`view_samples(hair_facing=)`): a view that looks along the hair shell (cos under HAIR_FACING)
#: sees it at its own outline, where each pixel is the whole shell's depth and a pose error of a
#: few degrees moves the sample across the hair's edge (onto the skin of the temple, the wall, or
#: the other way), while the views that face the shell see the Gaussian through the fewest layers
#: and count alike; the floor keeps every visible hair Gaussian a sample (the seen set, and so the
#: hidden hair's fill, does not change). The final build only, not the drafts the turned
#: keyframes are registered against (`VideoViews.hair_facing`). None: the visibility alone (the
#: rule before session 28). Session 28 (docs/video-build.md, "The hair's samples weighted by
#: facing (session 28)"); on since that session's merges (0.5)
HAIR_FACING: float | None = 0.5
#: ... the least share of that factor's root a grazing or backward view keeps
HAIR_FACING_FLOOR = 0.1
#: ... and with it, the hair Gaussians the reference view sees at a grazing angle or from behind
#: (cos < `MIN_COS`) of whose footprint its camera shows less than this share keep the blend's
#: colour after the photo's matching, as those only the other keyframes saw do
#: (`VideoViews.keep_view_colours`): the photo's matching pulls them to its own outline, the
#: keyframes that face them show their colour. What the photo shows more of (a bob's hair beside
#: the cheeks, seen from the front) keeps the photo's colour
HAIR_FACING_SHOWN = 0.2
#: the person mask is dilated by this share of the image's longer side before the hull test
SILHOUETTE_MARGIN = 0.02
#: a hair Gaussian is seen in a view when at least this share of its own footprint shows there
#: (`footprint_visibility`)
HAIR_VISIBLE = 0.1
#: a turned keyframe's person pixels this close to its fitted head (share of the longer side)
#: are relabelled by the reference view's colour models (`relabel_head`)
RELABEL_REACH = 0.06
#: the soft person mask: the segmentation's person mask blurred by this share of the image's
#: longer side (about the width of an anti-aliased silhouette at 192..512 px)
SOFT_MASK_SIGMA = 0.006
#: person pixels this close to the silhouette (share of the longer side) may be background
#: the segmentation took in (`soft_person`) ...
EDGE_BAND = 0.04
#: ... when their colour is this close (RGB in [0, 1], Euclidean) to the nearest background pixel's
BACKGROUND_COLOUR = 0.12

#: relabel the keyframes' heads by the reference's colour models (`relabel_head`)
RELABEL_KEYFRAMES = True
#: a turned keyframe's background-labelled pixels not of the background's colour beyond
#: `RELABEL_REACH` but within this share of the longer side of its fitted head are the
#: person's too (`relabel_head`) when they connect through such pixels to the person pixels by
#: the head (None: not). A keyframe turned to the profile has no face for the portrait
#: segmentation: its person is only what `relabel_head` finds within RELABEL_REACH of the
#: fitted head, and the strands hanging off a bob's nape lie beyond it (labelled background, the
#: hull growth never saw them missing). Session 21 (docs/video-build.md, "The bob's strand tips"):
#: the held-out bob +1.61 / +2.39 dB at +90 / -90 (seed 0; seeds 1, 2: +1.49 / +3.04, +1.59 /
#: +2.39), its front within 0.06; the sample avatar (seeds 0-2), the mesh subject and the whip
#: clip build the same to the digit; the held-out long_straight and ponytail styles +1.81 / +0.76
#: and +0.30 / +0.13 at +90 / -90, nothing lost over 0.03. 0.10: the bob 0.02-0.23 dB less at +-45 / +-90 (front
#: +0.05); 0.20: the same build as 0.15; the bob on the whip clip +0.12..+2.84 at every view
RELABEL_CONNECTED: float | None = 0.15
#: which keyframes RELABEL_CONNECTED applies to: "turned_end" (those registered at the turns'
#: ends, `View.info["turned_end"]`) or "all". "turned_end": with "all" the bob's keyframes
#: turned 15-45 degrees take in strands too, the first draft changes and its -80-degree frame
#: registers at -66 (-74.6): against the default before, front -0.35 / -45 -0.33 / -90 +1.73
#: dB ("turned_end": -0.06 / +0.58 / +2.39)
RELABEL_CONNECTED_IN = "turned_end"
#: a video build's wall plate (`VideoViews.plate`, `track.background_plate`) keeps the pixels
#: that match it out of `relabel_head`'s "not the wall model's colour" person: a cluttered
#: wall's poster and books are not the one-colour wall model's colour either. Only what of that
#: match survives an opening by a disc this share of the frame's longer side wide: the gaps
#: between strands (a pixel or two) stay the person's, as without a plate (None: no plate here;
#: session 22, docs/video-build.md "The wall behind the head")
RELABEL_PLATE: float | None = 0.01
#: ...and the pixels the plate does not know whose colour continues the known wall beside them: at
#: least `RELABEL_PLATE_MATCHES` known plate pixels within this share of the longer side agree with
#: it (`background_plate.AGREE`). On the cluttered wall the band of poster behind a turned head's
#: back lies inside the tracked head's zone in every frame; not the one-colour wall model's colour,
#: it was taken for the person (None: only the known plate; session 25, docs/video-build.md "The
#: wall above the head": on a plain wall the plate is the wall model's colour and nothing changes)
RELABEL_PLATE_NEAR: float | None = 0.03
RELABEL_PLATE_MATCHES = 3
#: a turned keyframe's body-labelled pixels in the colours of the video's known wall (the plate's
#: palette far from the head, `background_plate.wall_palette`) give no colour sample: the band of
#: wall behind a turned head's back lies inside the tracked head's zone in every frame (the plate
#: never knows it) and the segmentation calls it body; `SCALP_BODY` and the hair's renderer
#: visibility sampled it, and the hidden hair and scalp fills spread a handful of such samples
#: over the back of the head (the cluttered wall's poster red and book green: 22 Gaussians seen,
#: 211 filled). Skin and hair pixels are sampled as before; on a plain wall the palette is the
#: wall's one colour (session 25, second round, docs/video-build.md "The poster on the back of
#: the head"; False: body pixels sampled whatever their colour)
BODY_WALL = True
#: ...and neither do the body-labelled pixels within this share of the frame's longer side of
#: such a pixel (None: only those): the pixels at the outline between a turned head and the wall
#: behind it are a blend of the two (the camera's and the codec's mixing, a strand's fringe over
#: the wall), in neither the wall's palette nor the head's colours, and labelled body with the
#: wall; the person mask runs on into that wall, so `person_weight` does not weigh them down. On
#: the cluttered wall a few dozen such samples of the -80 degree frame (the poster's red mixed
#: with the hair's edge) were the only colour the scalp at the back of the crown saw, and the
#: scalp fill spread them over it: the red cast at the profile (the CLI's build: 501 Gaussians
#: facing away from the photo with red minus green > 0.3 -> 6). Session 27 (docs/video-build.md,
#: "The red at the back of the crown"), at 0.01 (drafts left out): the cluttered wall's sample
#: avatar +0.26 / +0.17 dB at +90 (seeds 0 / 1), the bob and the mesh subject within 0.01, no
#: view of the cluttered walls below -0.02; the white and teal walls the same to the digit; the
#: dark wall's sample avatar +0.09 at -90 (its grey wall, labelled body beside the back of the
#: head, blended the same way: a gain, for the reason the rule gives). On at 0.01 (switched on by
#: session 27's lead; the engineer left it off because the dark wall moved); None: only the palette's pixels
BODY_WALL_FRINGE: float | None = 0.01
#: ...in the drafts a video build registers its turned keyframes against (info["draft"]) too
#: (`VideoViews.fringes_wall`). False: the drafts sample those pixels as before, and the
#: registrations are as without the rule (in the drafts too, the refine rounds moved the
#: cluttered wall's keyframes by 0.25-0.75 degrees and the mesh subject lost 0.10 dB at +90, the
#: sample avatar 0.06 at +45 at seed 1)
BODY_WALL_FRINGE_IN_DRAFTS = False
#: the neck's Gaussians keep the portrait build's colour only where the reference view shows at
#: least this share of their footprint (`footprint_visibility`, `neck_kept`); the rest of the
#: neck (its sides and back, which the photo never shows) takes the keyframes' blend as the head
#: does. None: the whole neck keeps the portrait's colour (the rule before session 20: the
#: tracked head turns, the neck need not, so a turned keyframe's view of the neck is not the
#: rest avatar's; with the whole neck kept, its shadowed side is the single-frame fill, the lit
#: front's colour). Session 20 (docs/video-build.md, "The back of the head on the mesh subject"):
#: mesh subject +0.34 / +0.36 dB at +-90 (seed 1: +0.40 / +0.46), the front and +-45 within
#: 0.08; the other synthetic subjects within 0.03; the real clips have one keyframe (no views)
NECK_SHOWN: float | None = 0.02
#: the bald Gaussians of the scalp may take samples from a turned keyframe's body-labelled pixels
#: inside its fitted head's silhouette (`View.head`; `view_samples(body=)`): a portrait
#: segmentation calls the shadowed hair at a turned head's back body and `relabel_head` matches
#: it to neither colour model, so the scalp behind the ear kept the single-frame fill (skin).
#: Session 20 (docs/video-build.md, "The back of the head on the mesh subject"), with NECK_SHOWN:
#: mesh subject +0.28 / +0.33 dB at +-90 (seed 1 +0.20 / +0.23), the other synthetic subjects
#: within 0.01 (their scalp lies under their hair); every bald Gaussian so: the sample avatar -0.24
#: at -45
SCALP_BODY = True
#: the bald Gaussians of the scalp (as `SCALP_BODY` picks them) that no keyframe saw take the mean
#: colour of the `HAIR_NEIGHBOURS` nearest scalp Gaussians a keyframe did see, as hidden hair does
#: (`fill_hidden_hair`), instead of keeping the portrait build's fill: the scalp is where hair
#: grows, and the single view's fill there is the bald image's skin guess. On the mesh subject the
#: cap comes down behind the ear below the hair shell's level end, and the scalp's discs there
#: that the turned keyframes do not pass as seen (behind the build's own hair at the registered
#: pose, or at a grazing angle) stayed skin. Only where the reference view looks away (cos <
#: `MIN_COS`): what the photo faces keeps its fill. Session 21 (docs/video-build.md, "The hidden
#: scalp on the mesh subject"), eased clip, profile gain over the single-frame build: mesh
#: subject +1.73 -> +2.31 (seeds 1 / 2: +1.75 -> +2.44, +1.65 -> +2.28), sample avatar +3.20 ->
#: +3.44, bob +2.73 -> +2.97; whip clip +1.83 -> +2.34 / +0.85 -> +1.75; no view loses > 0.01 dB.
#: Session 21 left it off: the bob's video build (`avatarkit build VIDEO`) showed dark specks
#: across the face, the filled scalp (the hair's colour) seen through the holes the bald discs
#: drawn at random leave in the face; session 22 closed them (`bald_discs.HOLE_ALPHA`) and turned
#: it on (docs/video-build.md, "The face's holes (session 22)")
SCALP_FILL = True
#: ... and so do the drafts a video build registers its turned keyframes against
#: (`track.video_build`; their views carry info["draft"]). Off: the drafts keep the portrait's
#: fill there, so the colours the fill guesses from the poses read so far do not steer the
#: registration (the held-out bob at seed 1: its -80-degree frame registered at -58.4 instead of
#: -67.6 with it, -0.21 dB at the front; the mesh subject's turned frames came 2-5 degrees nearer
#: their true +-80, +0.05 dB of profile gain)
DRAFT_SCALP_FILL = False
#: the bald Gaussians outside the neck that no keyframe saw and that the scalp fill leaves (the
#: skin behind the ears, the nape under the hair's edge, the back of the ears), where the reference
#: view looks away (cos < `MIN_COS`), take the mean colour of the `HAIR_NEIGHBOURS` nearest bald
#: Gaussians outside the neck a keyframe did see (`fill_hidden_hair`), instead of keeping the
#: portrait build's fill, the lit front's skin carried round the head: what the turned keyframes
#: show beside them is the side of the head in its own shade. Not in the registration drafts
#: (info["draft"]), nor where the reference camera shows at least `HIDDEN_BALD_SHOWN` of the
#: Gaussian's footprint (`footprint_visibility`, as `NECK_SHOWN`): the photo's outline, seen
#: edge-on, keeps the photo's colour (filled there, the darker side's colour rimmed the front
#: view's cheeks and ears: the mesh subject's front -0.05 dB on the whip clip). Off: it lifts the
#: whip clip's mesh subject (profile gain +1.88 -> +2.09, seed 1 +1.80 -> +2.04) and nothing else,
#: the eased clip's mesh subject loses 0.03 of gain (-90 -0.04), the cluttered wall's sample avatar
#: 0.09 at -90. Session 26 (docs/video-build.md,
#: "The whip clip (session 26)")
HIDDEN_BALD_FILL = False
#: ... the share of a Gaussian's footprint the reference camera must show for it to keep its
#: colour under `HIDDEN_BALD_FILL`
HIDDEN_BALD_SHOWN = 0.02
#: a hair Gaussian the reference view shows edge-on (cos between the head's outward normal there
#: and the direction to the reference camera < `MIN_COS`) whose samples in the other labelled
#: keyframes fall on skin-labelled pixels for more than this share of their weight (skin + hair
#: labels) is dropped from the hair (`colour_from_views(drop_skin_hair=)`; None: kept). The
#: reference photo sees the sides of the head at its silhouette, where its hair label reaches
#: over the temples and ears the lifter's shell then covers; the keyframes turned toward that
#: side face it and see the skin there. Not in the drafts the turned keyframes are registered
#: against (`VideoViews.drops_skin_hair`): the registration reads the poses from them. Off.
#: Session 21 (docs/video-build.md, "The temples' hair on the mesh subject"), eased clip, 0.5
#: against None (front / +45 / -45 / +90 / -90 dB): mesh subject seed 0 +0.03 / +0.07 / +0.05 /
#: -0.01 / +0.07 (seed 1 within -0.01..+0.06), sample avatar +0.01..+0.20 (seed 1 +0.05..+0.14),
#: the held-out bob +0.48 / +0.37 / 0.00 / +0.35 / **-0.10** (seed 1 -0.39 at -90: strands
#: over its parting the keyframes see as skin between them); 0.7: the bob still -0.04 at -90,
#: the mesh subject -0.07 at +90
EDGE_HAIR_ON_SKIN: float | None = None
#: the neck's bald Gaussians that no keyframe saw and that `NECK_SHOWN` leaves to the blend (the
#: back and sides of the neck the photo does not show, which no keyframe faces at a usable angle
#: either) take the mean colour of the `HAIR_NEIGHBOURS` nearest neck Gaussians that have a
#: colour from the photo or the views (`fill_hidden_hair`), instead of keeping the portrait
#: build's fill: the single view's fill there is the lit front's skin carried round the neck,
#: while the neck's sides the turned keyframes do see show it in the shade it turns into. Not the
#: neck's underside (`NECK_FILL_DOWN`), nor in the drafts a video build registers its turned
#: keyframes against (info["draft"]). Off: on main's bald layer, whose discs stand 1-2 px past the
#: head's outline, the darker neck costs more over the white wall there than it gains inside (mesh
#: subject seed 0 -0.11 / -0.08 dB at +45 / -45, seed 1 -0.10 / -0.11; the sample avatar and the
#: bob within 0.02); with session 23's rim inset (`bald_discs.INSET`) it gains +0.31 / +0.40 at
#: +90 / -90 (seed 1 +0.34 / +0.44), nothing else moving more than 0.02: switch it on with that
#: (docs/video-build.md, "The back of the neck's colour (session 23)"). On since session 27 (the
#: lead, after the merges): scored over black as well (`benchmarks/build_video.py`), every view of
#: the mesh subject gains with it (seed 0 +0.17 / +0.20 at +45 / -45, +0.88 / +1.19 at +90 / -90),
#: so its loss over white is the overshooting rim's, as session 23 found; the mesh subject's profile
#: gain over white +2.88 / +3.17 / +3.14 -> +3.00 / +3.26 / +3.21 (seeds 0 / 1 / 2; +-45 -0.04..-0.10),
#: the sample avatar and the bob within 0.03 dB on every clip and wall measured
NECK_FILL = True
#: ... the neck's Gaussians whose normal points more than this many degrees below the horizontal
#: (the neck's cut end, under the head model's neck, which no view of a head shows but edge-on
#: at the outline) keep the portrait's fill
NECK_FILL_DOWN = 30.0
#: the bald layer's outline set in where the keyframes' own silhouettes say it overshoots
#: (`recede_outline`, the frame hull's `track.frame_hull.recede` with the keyframes as its
#: frames): a bald disc whose blending weight falls on the wall (`RECEDE_SHARE` of it) in
#: `RECEDE_QUORUM` of the keyframes that show it (at least `RECEDE_MIN_FRAMES`) moves inward
#: along its face's normal, `RECEDE_STEP` of a pixel a round, `RECEDE_ROUNDS` rounds at most,
#: the keyframes voting again on the moved head each round. The final build only, not the drafts
#: the turned keyframes are registered against (`VideoViews.recedes`). On (session 23, the lead,
#: after the engineer's figures, docs/video-build.md "The bald layer's outline from the keyframes
#: (session 23, second round)"): the video builds' fronts +0.5-0.7 dB (mesh subject, sample
#: avatar), +-45 up to +0.19, no view of any subject or seed below main's by more than 0.02 dB;
#: the +-90 views' outline is seen by no keyframe at its own outline, so #25's profile gain does
#: not move (mesh subject +2.58 -> +2.59)
RECEDE_KEYFRAMES = True
#: the keyframes' person masks (`recon.segment` labels not background) are dilated by this many
#: pixels before the wall is taken: at a turning video's 192 px the overshoot to find is 1-1.5 px,
#: so the frame hull's 1 px (`frame_hull.MARGIN`, for 480 px talking heads) would hide most of it
RECEDE_MARGIN = 0
#: a round's move, in pixels of the reference camera at the head (`bald_discs.camera_pixel`)
RECEDE_STEP = 0.5
#: rounds of `recede_outline` (at most RECEDE_ROUNDS x RECEDE_STEP pixels inward). 2 (a pixel):
#: with 4 the bob's front lost 0.09 dB (its neck's left edge set in past its truth's)
RECEDE_ROUNDS = 2
#: the keyframes vote at the poses the hair's outline stage uses (`VideoViews.outline_views`:
#: registered against the draft build where the video build did so), not the joint fit's. On:
#: the mesh subject's -45 / -90 +0.09 / +0.07 (seed 1 +0.23 / +0.08) over the joint fit's poses,
#: the front -0.18 (-0.25); the sample avatar and the bob the same to the digit
RECEDE_OUTLINE_POSES = True
#: the discs on the scalp (a host face's vertex in the head model's "scalp" region, as
#: `VideoViews.scalp_rows`) recede too. False: they stay on the surface, under the hair (the
#: scalp's outline is the hair's; set in, the crown of the sample avatar's short hair showed the
#: wall through at the whip clip's +-45: -0.62 / -0.57 dB, kept -0.02 / +0.07)
RECEDE_SCALP = False
#: a keyframe votes a disc outside when this share of its blending weight there is on the wall
RECEDE_SHARE = 0.3
#: ... and a disc moves when at least this share of the keyframes showing it vote so ...
RECEDE_QUORUM = 0.3
#: ... and it shows in at least this many keyframes
RECEDE_MIN_FRAMES = 2
#: pixels (of a keyframe's image): a keyframe counts in a disc's quorum, shown or voting, only where
#: the disc's centre lies within this of that keyframe's render outline (`frame_hull.near_outline`),
#: and a disc so counted by at least `RECEDE_EDGE_FRAMES` keyframes moves as the quorum says. A
#: keyframe that sees a disc face on, well inside the avatar's outline, cannot tell whether it
#: stands out of the surface, yet without this it counts against the move: the profile's discs
#: (the face's profile line, the back of the neck), which only the turned keyframes see at their
#: outline, showed in 6-8 keyframes and were voted out by 2-3 of them, under the quorum. None:
#: every keyframe that shows a disc counts (session 23's rule). Off (session 26, docs/video-build.md
#: "The profile's outline seen at the keyframes' outlines"): at 4 px the mesh subject's profile gain
#: +2.66 / +2.93 / +2.88 -> +2.73 / +3.01 / +2.99 (seeds 0 / 1 / 2), the bob within 0.04 dB, but one
#: keyframe's vote now moves a disc, and where a keyframe's pose is off the sample avatar loses:
#: -0.12 at +45 (seed 0), -0.28..-0.65 on the whip clip, -0.53..-0.71 on the cluttered wall. On
#: since session 27 with only the far-turned keyframes leading it (`RECEDE_EDGE_TURN`; docs/
#: video-build.md "The profile's outline led by the turn ends (session 27)")
RECEDE_EDGE = 4.0
#: with `RECEDE_EDGE`, the keyframes a disc must lie near the outline of (instead of
#: `RECEDE_MIN_FRAMES`): one, since a contour is seen edge-on by few keyframes
RECEDE_EDGE_FRAMES = 1
#: with `RECEDE_EDGE`, a keyframe votes a disc outside when this share of its blending weight there
#: is on the wall (instead of `RECEDE_SHARE`): one keyframe may now decide, so its vote asks for a
#: clearer overshoot
RECEDE_EDGE_SHARE = 0.3
#: degrees, with `RECEDE_EDGE`: only the keyframes turned at least this far from the reference
#: (`turned_yaws`: the yaw of their camera about the head, seen from the reference camera's axes)
#: lead the edge rule. A disc then moves as session 23's quorum says (every keyframe that shows it),
#: or where one of these keyframes votes it out and the edge rule's quorum (the keyframes that see
#: it at their outline) holds. A keyframe turned by t sees at its outline the discs that face
#: 90 - t from the front-back axis: past 60 degrees the face's profile line, the throat and the
#: back of the neck, which only the one or two keyframes at each turn's end see edge-on and the
#: rest see face on. The near-frontal keyframes' outline (the cheeks, the jaw's sides) lies at the
#: outline of several of them, and there session 23's agreement (the turned keyframes that see it
#: face on counted) stays: on the disc-made sample avatar, whose truth overshoots as the build does,
#: their votes alone set the outline in past the truth (the whip clip's +45 -0.46 dB). None: every
#: keyframe leads (session 26's rule). 60 (session 27): the mesh subject's profile gain +2.66 /
#: +2.93 / +2.88 -> +2.77 / +3.07 / +3.00 (seeds 0 / 1 / 2), the sample avatar and the bob on
#: the white and cluttered walls and the whip clip within 0.02 dB of main's, none of their views
#: lower by more (docs/video-build.md "The profile's outline led by the turn ends (session 27)")
RECEDE_EDGE_TURN = 60.0
#: with `RECEDE_EDGE_TURN`: a turned keyframe leads only where its silhouette agrees with the
#: avatar's beyond the outline's band: at most this many pixels of its wall lie under the avatar's
#: render more than `RECEDE_EDGE_DEEP` pixels inside the render's outline, per pixel of that outline
#: (`deep_disagreement`). The recession mends a pixel or two of overshoot; a keyframe that puts the
#: avatar's inside over its wall disagrees by more than that (its pose or its segmentation is off:
#: the cluttered wall's sample avatar's -80 end, read 92 degrees from the reference, 1.0; the
#: bob's -80 end, 0.23), and its near-outline votes would move the outline where it is wrong. The
#: keyframes whose silhouettes fit (0.00-0.02 at the white wall's turn ends; the mesh subject's
#: tracking edge 0.09) lead. None: no test
RECEDE_EDGE_AGREE = 0.1
#: ... pixels: the outline's band `RECEDE_EDGE_AGREE` leaves out (the overshoot the recession mends)
RECEDE_EDGE_DEEP = 2.0
#: with `RECEDE_EDGE_TURN`: a leading keyframe's wall leaves out the pixels whose colour lies within
#: this many levels (of 255, every channel) of the person's nearest to them (`sure_wall`): where the
#: wall looks like the skin beside it the segmentation's edge is a guess, and one keyframe's guess
#: would move the outline (the cluttered wall's beige plaster behind the sample avatar's neck at its
#: +80 end: the wall label a pixel inside the neck's back, -0.10 dB at -90). On a white wall the
#: skin's outline is 40+ levels off it even where the frame blends the two. None: the labels' wall
RECEDE_EDGE_LIKE = 40
#: with `RECEDE_EDGE_TURN`: the rounds the turned keyframes' votes set discs in (None:
#: `RECEDE_ROUNDS`); the rounds past `RECEDE_ROUNDS` move only the discs they lead
RECEDE_EDGE_ROUNDS = None
#: The bald layer's colours come from a keyframe's `skin_pose` where it has one (`VideoViews.
#: skin_views`; only `track.video_build.SKIN_POSE` sets one): a frame then has two poses, the
#: plain registration's for the hair and everything the hair is made from, and the one found with
#: the draft's hair discounted for the skin. Not in a registration draft (info["draft"]) unless
#: this is True: coloured so, the second draft's skin is nearer the frames' and the plain poses
#: round 2 registers against it read further (the mesh subject's +80 end 68.3 -> 69.3; its profile
#: gain +2.66 -> +2.80, seed 1 +2.94), but the hair's poses move too and the held-out bob, whose
#: build agrees with its plain poses, lost 0.12 dB at -90 (seed 1; session 25, docs/video-build.md)
SKIN_POSE_IN_DRAFTS = False
#: the bald outline's recession (`recede_outline`) votes with the keyframes' skin poses too (the
#: outline the frames show over the wall is the skin's): the mesh subject +0.00..+0.03 dB, the bob
#: as without (seed 0)
SKIN_POSE_RECEDE = True

_CV = np.diag([1.0, -1.0, -1.0])


@dataclass
class View:
    """One keyframe seen by the rest avatar: image (H, W, 3) uint8; camera (rest frame ->
    image); labels (H, W) int32 segmentation (None: not segmented); sharpness in [0, 1];
    frame: the video frame number; reference: the portrait build's view; head (H, W) bool:
    the fitted head mesh seen by the camera (`head_silhouette`; None: unknown)."""

    image: np.ndarray
    camera: Camera
    labels: np.ndarray | None = None
    sharpness: float = 1.0
    frame: int = -1
    reference: bool = False
    info: dict = field(default_factory=dict)
    head: np.ndarray | None = None


def pose_matrix(rotation, translation) -> np.ndarray:
    """(4, 4) X_view = R X + t from axis-angle rotation (3,) and translation (3,)."""
    from avatarkit.rotations import axis_angle_to_matrix

    m = np.eye(4)
    m[:3, :3] = axis_angle_to_matrix(np.asarray(rotation, np.float64))
    m[:3, 3] = np.asarray(translation, np.float64)
    return m


def keyframe_cameras(build_camera: Camera, build_pose: np.ndarray, reference_pose: np.ndarray,
                     poses: list[np.ndarray]) -> list[Camera]:
    """Cameras of the avatar's rest frame for keyframe poses (4, 4) (module docstring): the
    build's camera intrinsics, extrinsics C M_k M_r^-1 M_b. build_pose: M_b; reference_pose: M_r."""
    fix = np.linalg.inv(reference_pose) @ build_pose
    out = []
    for m in poses:
        w2c = np.eye(4)
        w2c[:3] = (np.diag([1.0, -1.0, -1.0, 1.0]) @ m @ fix)[:3]
        c = build_camera
        out.append(Camera(c.fx, c.fy, c.cx, c.cy, c.width, c.height, w2c))
    return out


def camera_centre(camera: Camera) -> np.ndarray:
    """(3,) the camera's position in its world."""
    return np.asarray(camera.camera_center, np.float64)


def head_silhouette(vertices: np.ndarray, faces: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) bool: the pixels a mesh (vertices (V, 3) in the camera's world, faces (F, 3))
    covers (`synthetic.mesh_raster.rasterise`: pixel centres inside a triangle in front of the
    camera)."""
    from avatarkit.synthetic.mesh_raster import rasterise

    v = np.asarray(vertices, np.float64)
    return rasterise(v, faces, np.zeros((len(v), 1)), camera).covered


@dataclass
class Samples:
    """One view's samples: seen (N,) bool; weight (N,) float64 (0 where not seen); colour (N, 3)
    float32 in [0, 1] (valid where seen)."""

    seen: np.ndarray
    weight: np.ndarray
    colour: np.ndarray


def footprint_visibility(gaussians, camera: Camera, region: np.ndarray | None = None) -> np.ndarray:
    """(N,) float64 in [0, 1]: the share of each Gaussian's own footprint that the renderer
    composites into `region` (H, W) bool (None: the whole image): its blending weight
    alpha_i T_i summed over the region's pixels (`label_lifting.accumulate_view`, the renderer's
    compositing) over the same sum with nothing in front of it and no edge, opacity_i x 2 pi /
    sqrt(det conic_i) (the integral of its projected 2D Gaussian). A Gaussian in front of
    everything, well inside the region, reads ~1; half hidden behind an opaque surface ~0.5;
    behind the hair's outer layer or outside the region ~0. This is what a hair Gaussian's
    visibility is judged by: the hair shell's outward direction is no surface normal to face."""
    from avatarkit.recon.label_lifting import accumulate_view
    from avatarkit.render import project_gaussians

    h, w = camera.height, camera.width
    labels = np.ones((h, w), np.int32) if region is None else np.asarray(region, bool).astype(np.int32)
    weights, _, _ = accumulate_view(gaussians, camera, labels, 2)
    proj = project_gaussians(gaussians, camera)
    c = np.asarray(proj.conics, np.float64)
    det = c[:, 0] * c[:, 2] - c[:, 1] ** 2
    own = np.asarray(gaussians.opacities, np.float64) * 2.0 * np.pi / np.sqrt(np.maximum(det, 1e-30))
    vis = np.where((proj.radii > 0) & (det > 0), weights[:, 1] / np.maximum(own, 1e-30), 0.0)
    return np.clip(vis, 0.0, 1.0)


def neck_kept(neck: np.ndarray, gaussians, reference: Camera, shown: float) -> np.ndarray:
    """(N,) bool: the rows of `neck` (N,) bool whose footprint the reference camera shows at
    least `shown` of (`footprint_visibility`): the neck's Gaussians that keep the portrait
    build's colour under `NECK_SHOWN`; the neck the photo does not show is left to the blend."""
    neck = np.asarray(neck, bool)
    if not neck.any():
        return neck.copy()
    return neck & (footprint_visibility(gaussians, reference) >= float(shown))


def reference_colours(image: np.ndarray, labels: np.ndarray):
    """(hair, skin) `recon.segment.ColourModel`s (Lab) of the reference view: image (H, W, 3)
    uint8, labels (H, W) int; None when either label has fewer than 20 pixels (a bald subject:
    no hair model, so `relabel_head` leaves the keyframes' labels alone)."""
    from avatarkit.recon.segment import HAIR, SKIN, ColourModel, rgb_to_lab

    labels = np.asarray(labels)
    hair, skin = labels == HAIR, labels == SKIN
    if hair.sum() < 20 or skin.sum() < 20:
        return None
    lab = rgb_to_lab(np.asarray(image))
    return ColourModel.fit(lab[hair]), ColourModel.fit(lab[skin])


def plate_wall(plate, image: np.ndarray):
    """(wall (H, W) bool, its colour (H, W, 3) uint8): the pixels of a keyframe's image (H, W, 3)
    uint8 that show the video's wall (`Plate.matches`) opened by `RELABEL_PLATE` (share of the
    longer side, at least a pixel), and the plate's colour there; None without a plate or with
    `RELABEL_PLATE` None."""
    import cv2

    opening = RELABEL_PLATE
    if plate is None or opening is None:
        return None
    wall = plate.matches(image).astype(np.uint8)
    r = max(1, int(round(opening * max(wall.shape))))
    wall = cv2.morphologyEx(wall, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)) > 0
    colour, known = plate.at(wall.shape)
    near = RELABEL_PLATE_NEAR
    if near is not None:
        cont = _continues_plate(np.asarray(image), colour, known, max(1, int(round(near * max(wall.shape)))))
        colour = colour.copy()
        colour[cont] = np.asarray(image)[cont]
        wall = wall | cont
    return wall, colour


def wall_palette_pixels(plate, image: np.ndarray):
    """(H, W) bool: the pixels of a keyframe's image (H, W, 3) uint8 whose colour is in the
    palette of the video's known wall far from the head (`background_plate.wall_palette`), or
    None without a plate (or with no known wall)."""
    from avatarkit.track import background_plate

    if plate is None:
        return None
    colour, known = plate.at(np.asarray(image).shape[:2])
    if not known.any():
        return None
    table = background_plate.wall_palette(known, colour)
    return background_plate.in_palette(table, np.asarray(image))


def _continues_plate(image: np.ndarray, colour: np.ndarray, known: np.ndarray, r: int) -> np.ndarray:
    """(H, W) bool: the pixels of image (H, W, 3) uint8 the plate does not know (`known` (H, W)
    bool, its colour (H, W, 3)) where at least `RELABEL_PLATE_MATCHES` known plate pixels within
    r px are within `background_plate.AGREE` of the image's colour in every channel."""
    import cv2

    from avatarkit.track import background_plate

    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
    todo = ~known & (cv2.dilate(known.astype(np.uint8), disc) > 0)
    return todo & background_plate.continues(known, colour, image, todo, r, RELABEL_PLATE_MATCHES)


def relabel_head(labels: np.ndarray, image: np.ndarray, head: np.ndarray, colours,
                 reach: float | None = None, connected: float | None = None,
                 wall: np.ndarray | None = None) -> np.ndarray:
    """(H, W) labels of a turned keyframe with its head's pixels relabelled hair or skin by the
    reference view's colour models. A portrait segmentation finds hair in a zone laid out
    around a frontal face: in a keyframe turned 20-35 degrees it labels the hair over the ear
    and at the back of the head "body" (or loses it to the background), so that hair is
    neither sampled nor voted for, and the silhouette bound removes hair through it. The
    reference view's segmentation is the one made on the picture it is made for; its skin and
    hair colours (`colours`: `reference_colours`, None: labels unchanged) label the keyframe's
    person pixels within `reach` (share of the longer side) of the fitted head mesh as seen by
    that keyframe (`head`, (H, W) bool): hair where the hair model is the likelier and the
    colour is within `segment.MATCH_D2` of it, skin likewise; other pixels keep their label.
    Background-labelled pixels there whose colour is not within `segment.MATCH_D2` of the
    background's (away from the head) are the person's too: body at least (shadowed hair on
    the turned side may match neither model), hair or skin when they match. connected: such
    pixels beyond `reach` but within `connected` (share of the longer side) of the head count
    too where they connect through such pixels to the person pixels by the head
    (`_connected_lost`, `RELABEL_CONNECTED`; None: not). wall: (`plate_wall`) the pixels that
    show the video's wall and the wall's colour there, or None: where that colour is not the
    wall model's either (a cluttered wall is not one colour) they are never taken for the person
    by their colour; where it is (a plain wall) nothing changes.
    labels: (H, W) int; image: (H, W, 3) uint8."""
    reach = RELABEL_REACH if reach is None else reach
    import cv2

    from avatarkit.recon.segment import BACKGROUND, BODY, HAIR, MATCH_D2, SKIN, ColourModel, rgb_to_lab

    labels = np.asarray(labels).copy()
    if colours is None:
        return labels
    hair_m, skin_m = colours
    r = max(1, int(round(reach * max(labels.shape))))
    near = cv2.dilate(np.asarray(head, np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)) > 0
    full = rgb_to_lab(np.asarray(image))
    zone = near & (labels != BACKGROUND)
    bg = (labels == BACKGROUND) & ~near
    candidates = near & (labels == BACKGROUND)
    if bg.sum() >= 20 and candidates.any():
        # the segmentation's person mask loses dark hair at a turned head's back: a pixel it
        # calls background by the head is the person's when its colour is not the background's
        # (the model from every 4th background pixel: the same fit, a quarter of the work)
        model = ColourModel.fit(full[bg][::4])
        lost = np.zeros_like(candidates)
        lost[candidates] = model.distance2(full[candidates]) > MATCH_D2
        if wall is not None:
            shown, colour = wall
            # the wall the plate shows where it is not the one-colour model's (a plain wall's
            # edge pixels a few levels off its flat colour stay the rule's, as without a plate)
            wall = shown.copy()
            wall[shown] = model.distance2(rgb_to_lab(colour[shown])) > MATCH_D2
            lost &= ~wall
        if connected is not None:
            lost |= _connected_lost(labels, full, head, near, zone | lost, model, connected, wall)
        labels[lost] = BODY
        zone |= lost
    lab = full[zone]
    dh, ds = hair_m.distance2(lab), skin_m.distance2(lab)
    lh, ls = hair_m.log_likelihood(lab), skin_m.log_likelihood(lab)
    new = labels[zone]
    new[(lh > ls) & (dh <= MATCH_D2)] = HAIR
    new[(ls >= lh) & (ds <= MATCH_D2)] = SKIN
    labels[zone] = new
    return labels


def _connected_lost(labels: np.ndarray, lab: np.ndarray, head: np.ndarray, near: np.ndarray,
                    person: np.ndarray, background, reach: float, wall: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: background-labelled pixels beyond `near` but within `reach` (share of the
    longer side) of the fitted head `head`, whose Lab colour `lab` (H, W, 3) is not the
    `background` model's (squared distance > `segment.MATCH_D2`) and which connect through such
    pixels to `person` (the head zone's person pixels) (`RELABEL_CONNECTED`); wall: (H, W) bool
    pixels of the video's wall, never such pixels (None: none)."""
    import cv2
    from scipy import ndimage

    from avatarkit.recon.segment import BACKGROUND, MATCH_D2

    r = max(1, int(round(reach * max(labels.shape))))
    wide = cv2.dilate(np.asarray(head, np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)) > 0
    far = wide & ~near & (np.asarray(labels) == BACKGROUND)
    out = np.zeros_like(far)
    if not far.any() or not person.any():
        return out
    out[far] = background.distance2(lab[far]) > MATCH_D2
    if wall is not None:
        out &= ~wall
    # 8-connected: a strand a pixel wide runs diagonally as often as not
    comp, _ = ndimage.label(out | person, structure=np.ones((3, 3), bool))
    keep = np.unique(comp[person])
    return out & np.isin(comp, keep[keep > 0])


def soft_person(labels: np.ndarray, image: np.ndarray | None = None, sigma: float | None = None) -> np.ndarray:
    """(H, W) float32 in [0, 1]: the segmentation's person mask (label != background) blurred
    by sigma x the longer side: ~0.5 on the silhouette, 1 well inside, 0 well outside.
    With the image (H, W, 3) uint8, person pixels within `EDGE_BAND` of the silhouette whose
    colour is within `BACKGROUND_COLOUR` of the nearest background pixel's count as background
    first: a segmentation whose edge sits a few pixels out in the background (a halo labelled
    hair) would otherwise pass background colour off as the person's."""
    sigma = SOFT_MASK_SIGMA if sigma is None else sigma
    import cv2
    from scipy import ndimage

    from avatarkit.recon.segment import BACKGROUND

    bg = np.asarray(labels) == BACKGROUND
    person = ~bg
    if image is not None and bg.any() and person.any():
        band = max(1.0, EDGE_BAND * max(bg.shape))
        dist, (iy, ix) = ndimage.distance_transform_edt(person, return_indices=True)
        img = np.asarray(image, np.float32) / 255.0
        near = person & (dist <= band)
        diff = np.linalg.norm(img[near] - img[iy[near], ix[near]], axis=1)
        looks_bg = np.zeros_like(person)
        looks_bg[near] = diff < BACKGROUND_COLOUR
        # only background-coloured pixels connected to the background through such pixels
        # (a light patch inside the head is not a halo)
        grown, _ = ndimage.label(bg | looks_bg)
        touching = np.unique(grown[bg])
        person = person & ~(looks_bg & np.isin(grown, touching[touching > 0]))
    s = max(0.5, sigma * max(person.shape))
    return np.clip(cv2.GaussianBlur(person.astype(np.float32), (0, 0), s), 0.0, 1.0)


def person_weight(labels: np.ndarray, px: np.ndarray, image: np.ndarray | None = None) -> np.ndarray:
    """(N,) float64 in [0, 1]: how much a sample at pixels px (N, 2) is the person's and not
    the background's: clip(2 p - 1, 0, 1) with p the soft person mask there (`soft_person`),
    so a pixel on the silhouette (half background) gives nothing and one a few pixels inside
    gives its full weight. A pixel outside the image or px not finite gives 0. image: the
    view's image (H, W, 3) uint8, for the background-colour test of `soft_person`."""
    return _person_weight(soft_person(labels, image), px)


def _person_weight(soft: np.ndarray, px: np.ndarray) -> np.ndarray:
    from avatarkit.recon.image_sampling import lookup

    px = np.asarray(px, np.float64)
    ok = np.isfinite(px).all(axis=1)
    p = np.zeros(len(px))
    if ok.any():
        p[ok] = lookup(soft, px[ok])
    return np.clip(2.0 * p - 1.0, 0.0, 1.0)


def view_samples(gaussians, normals: np.ndarray, view: View, sample_labels=None,
                 depth_tolerance: float | None = None, render_result=None, min_cos: float | None = None,
                 hair: np.ndarray | None = None, body: np.ndarray | None = None,
                 hair_facing: float | None = None) -> Samples:
    """Visibility, weight and colour of every Gaussian in one view (module docstring).
    normals: (N, 3) unit outward normals. sample_labels: labels whose pixels may be sampled
    (default skin and hair; None labels in the view: every pixel). min_cos: the facing cut
    (-1: none; the weight is still cos^2, zero for Gaussians facing away).
    hair: (N,) bool, the Gaussians whose visibility is the renderer's (`footprint_visibility`
    on the view's person pixels, `soft_person` >= 0.5, at least `HAIR_VISIBLE`) instead of the
    depth, facing and label test; their weight is that visibility x sharpness. Where the view
    has labels every sample's weight is multiplied by `person_weight` (a pixel on the
    silhouette, half background, gives nothing) and a zero weight is no sample. body: (N,) bool,
    the Gaussians that may also sample body-labelled pixels inside the view's fitted head
    (`View.head`) when the view is not the reference (`SCALP_BODY`). hair_facing: the hair rows'
    weight is also multiplied by min(1, max(cos / hair_facing, `HAIR_FACING_FLOOR`)) ^
    `COS_POWER` (`HAIR_FACING`; None: not)."""
    depth_tolerance = DEPTH_TOLERANCE if depth_tolerance is None else depth_tolerance
    min_cos = MIN_COS if min_cos is None else min_cos
    from avatarkit.recon.image_sampling import sample_image
    from avatarkit.recon.segment import HAIR, SKIN
    from avatarkit.recon.visibility import seen_from
    from avatarkit.render import render

    cam = view.camera
    r = render_result if render_result is not None else render(gaussians, cam, background=(0.0, 0.0, 0.0))
    seen, px, cos = seen_from(np.asarray(gaussians.means, np.float64), np.asarray(normals, np.float64), cam,
                              r.depth, cam, tol=depth_tolerance, min_facing=min_cos)
    px = np.asarray(px, np.float64)
    ix = np.clip(np.floor(np.where(np.isfinite(px), px, 0)).astype(np.int64), 0, [cam.width - 1, cam.height - 1])
    seen &= r.alpha[ix[:, 1], ix[:, 0]] > ALPHA_MIN
    if view.labels is not None:
        import cv2

        allowed = (SKIN, HAIR) if sample_labels is None else tuple(sample_labels)
        e = int(round(EDGE_MARGIN * max(view.labels.shape)))

        def inside(region):
            region = region.astype(np.uint8)
            if e > 0:
                region = cv2.erode(region, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * e + 1, 2 * e + 1)))
            return region[ix[:, 1], ix[:, 0]] > 0

        region = np.isin(view.labels, allowed)
        ok = inside(region)
        if body is not None and np.any(body) and not view.reference and view.head is not None:
            from avatarkit.recon.segment import BODY

            wide = region | ((np.asarray(view.labels) == BODY) & np.asarray(view.head, bool))
            ok = np.where(np.asarray(body, bool), inside(wide), ok)
        seen &= ok
    weight = np.clip(cos, 0, 1) ** COS_POWER
    soft = None if view.labels is None else soft_person(view.labels, view.image)
    if hair is not None and np.any(hair):
        hair = np.asarray(hair, bool)
        # hair may show over any part of the person (a turned head's back reads "body" to a
        # portrait segmentation); the renderer decides whether it is the surface seen there
        vis = footprint_visibility(gaussians, cam, None if soft is None else soft >= 0.5)
        inside = np.isfinite(px).all(axis=1) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) \
            & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        seen = np.where(hair, inside & (vis >= HAIR_VISIBLE), seen)
        hair_weight = vis
        if hair_facing is not None:
            # a view along the shell samples the hair's own outline (`HAIR_FACING`)
            hair_weight = vis * np.clip(cos / float(hair_facing), float(HAIR_FACING_FLOOR), 1.0) ** COS_POWER
        weight = np.where(hair, hair_weight, weight)
    wall_coloured = view.info.get("wall_coloured")
    if BODY_WALL and wall_coloured is not None and view.labels is not None and not view.reference:
        from avatarkit.recon.segment import BODY

        # the wall seen past a turned head, labelled body (`BODY_WALL`): no sample, any layer
        body_px = np.asarray(view.labels) == BODY
        on = body_px & np.asarray(wall_coloured, bool)
        fringe = BODY_WALL_FRINGE
        if fringe is not None and on.any() and view.info.get("wall_fringe", True):
            import cv2

            # ...nor the body pixels beside it: the head's outline blended with that wall
            # (`BODY_WALL_FRINGE`)
            r = max(1, int(round(float(fringe) * max(on.shape))))
            disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
            on = body_px & (cv2.dilate(on.astype(np.uint8), disc) > 0)
        seen &= ~on[ix[:, 1], ix[:, 0]]
    weight = np.where(seen, weight * float(view.sharpness), 0.0)
    if soft is not None:
        weight *= _person_weight(soft, px)
        seen &= weight > 0
    weight *= REFERENCE_WEIGHT if view.reference else 1.0
    colour = np.zeros((len(gaussians), 3), np.float32)
    if seen.any():
        colour[seen] = sample_image(view.image.astype(np.float32) / 255.0, px[seen])
    return Samples(seen, weight, colour)


def blend_colours(current: np.ndarray, samples: list[Samples], keep: np.ndarray | None = None,
                  current_weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) colours: the weighted mean of the views' samples where any view saw the Gaussian,
    `current` elsewhere and where `keep` (N,) bool. current_weight: (N,) weight of `current`
    in the mean (default 0). Returns (colours, seen (N,) bool)."""
    current = np.asarray(current, np.float32)
    num = np.zeros((len(current), 3))
    den = np.zeros(len(current))
    for s in samples:
        num += s.weight[:, None] * s.colour
        den += s.weight
    seen = den > 0
    if keep is not None:
        seen &= ~np.asarray(keep, bool)
    if current_weight is not None:
        num += current_weight[:, None] * current
        den += current_weight
    out = current.copy()
    out[seen] = (num[seen] / den[seen, None]).astype(np.float32)
    return np.clip(out, 0.0, 1.0), seen


def refine_colours_views(gaussians, normals: np.ndarray, views: list[View], iterations: int = 4,
                         step: float = 1.0, min_weight: float = 0.05):
    """`recon.assemble.refine_colours` over several views: each round renders every labelled
    view, takes its residual inside the view's skin + hair region and, per Gaussian that shows
    there (blending weight summed over the region >= min_weight pixels), the residual averaged
    over its footprint, as refine_colours does; a Gaussian's update is the mean of its views'
    updates weighted by (1e-3 + cos^2) x sharpness (x `REFERENCE_WEIGHT` for the reference), so
    with the reference view alone this is refine_colours. Returns (recoloured set, figures:
    mean PSNR over the views' regions before and after)."""
    from avatarkit.recon.assemble import footprint_residuals, psnr
    from avatarkit.recon.label_lifting import accumulate_weights
    from avatarkit.recon.segment import HAIR, SKIN
    from avatarkit.render import render

    gs = gaussians
    rgb = gs.colors.astype(np.float32)
    prep = []
    for v in views:
        if v.labels is None:
            continue
        cam = v.camera
        m = np.isin(v.labels, (SKIN, HAIR))
        target = v.image.astype(np.float32) / 255.0
        bg = np.median(target[~m], axis=0) if (~m).any() else np.zeros(3, np.float32)
        px, _ = cam.project(gs.means)
        shows = accumulate_weights(gs, cam, m.astype(np.int32), 2)[:, 1] >= min_weight
        shows &= np.isfinite(px).all(axis=1)
        to_cam = camera_centre(cam)[None] - np.asarray(gs.means, np.float64)
        to_cam /= np.maximum(np.linalg.norm(to_cam, axis=1, keepdims=True), 1e-12)
        cos = np.clip(np.einsum("ij,ij->i", np.asarray(normals, np.float64), to_cam), 0, 1)
        w = (1e-3 + cos ** 2) * float(v.sharpness) * (REFERENCE_WEIGHT if v.reference else 1.0)
        prep.append(dict(cam=cam, m=m, target=target, bg=bg, px=px, shows=shows, w=w, level=None))
    history = []
    for it in range(iterations + 1):
        num = np.zeros((len(gs), 3))
        den = np.zeros(len(gs))
        scores = []
        for p in prep:
            r = render(gs, p["cam"], background=p["bg"])
            scores.append(psnr(r.rgb, p["target"], p["m"]))
            if it == iterations or not p["shows"].any():
                continue
            sh = p["shows"]
            delta, p["level"] = footprint_residuals(r.rgb, p["target"], p["m"], p["px"][sh],
                                                    r.meta["radii"][sh], p["level"])
            num[sh] += p["w"][sh, None] * delta
            den[sh] += p["w"][sh]
        history.append(float(np.mean(scores)) if scores else float("nan"))
        if it == iterations or not (den > 0).any():
            break
        upd = den > 0
        rgb[upd] = np.clip(rgb[upd] + step * (num[upd] / den[upd, None]).astype(np.float32), 0.0, 1.0)
        gs = gs.with_colors(rgb)
    return gs, {"views": len(prep), "psnr_before": round(history[0], 3), "psnr_after": round(history[-1], 3)}


def fill_hidden_hair(means: np.ndarray, colours: np.ndarray, source: np.ndarray, target: np.ndarray,
                     k: int | None = None) -> tuple[np.ndarray, int]:
    """colours (N, 3) with rows `target` (N,) bool replaced by the mean colour of their k nearest
    `source` (N,) bool rows (by centre). Returns (colours, rows filled)."""
    k = HAIR_NEIGHBOURS if k is None else k
    from scipy.spatial import cKDTree

    out = np.asarray(colours, np.float32).copy()
    if not source.any() or not target.any():
        return out, 0
    k = int(min(k, source.sum()))
    _, idx = cKDTree(np.asarray(means)[source]).query(np.asarray(means)[target], k=k)
    idx = np.asarray(idx).reshape(int(target.sum()), k)
    out[target] = out[source][idx].mean(axis=1)
    return out, int(target.sum())


def silhouette_outside(points: np.ndarray, views: list[View], margin: float | None = None) -> np.ndarray:
    """(P,) int: in how many labelled views the point projects inside the image but outside
    the dilated person mask (module docstring; the mask is `soft_person` >= 0.5, without the
    background-coloured halo a segmentation may take in, joined with the view's `head`)."""
    margin = SILHOUETTE_MARGIN if margin is None else margin
    import cv2

    count = np.zeros(len(points), np.int64)
    for v in views:
        if v.labels is None:
            continue
        person = (soft_person(v.labels, v.image) >= 0.5).astype(np.uint8)
        r = max(1, int(round(margin * max(person.shape))))
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        if v.head is not None:
            # the person's silhouette holds the fitted head (eroded by the same margin: the
            # pose's error): a segmentation with a hole there (a keyframe's face partly
            # labelled background) is no evidence against the hair in it
            person |= cv2.erode(v.head.astype(np.uint8), disc)
        person = cv2.dilate(person, disc)
        px, z = v.camera.project(points)
        px = np.asarray(px, np.float64)
        h, w = person.shape
        inside = np.isfinite(px).all(axis=1) & (np.asarray(z) > 0)
        inside &= (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        ix = np.clip(np.floor(np.where(inside[:, None], px, 0)).astype(np.int64), 0, [w - 1, h - 1])
        count += inside & (person[ix[:, 1], ix[:, 0]] == 0)
    return count


def label_weights(means: np.ndarray, samples: list[Samples], views: list[View], labels) -> np.ndarray:
    """(N,) the summed sample weight of the non-reference labelled views whose segmentation
    labels one of `labels` at the pixel each Gaussian's centre (means (N, 3)) projects to."""
    out = np.zeros(len(means))
    for s, v in zip(samples, views):
        if v.reference or v.labels is None:
            continue
        px, _ = v.camera.project(means)
        px = np.asarray(px, np.float64)
        h, w = v.labels.shape
        ix = np.clip(np.floor(np.where(np.isfinite(px), px, 0)).astype(np.int64), 0, [w - 1, h - 1])
        on = np.isin(v.labels[ix[:, 1], ix[:, 0]], labels)
        out += np.where(s.seen & on, s.weight, 0.0)
    return out


def colour_from_views(bald, hair, views: list[View], normals: np.ndarray, keep: np.ndarray | None = None,
                      body: np.ndarray | None = None, scalp: np.ndarray | None = None,
                      drop_skin_hair: bool = False, neck: np.ndarray | None = None,
                      bald_views: list[View] | None = None, hidden_bald: np.ndarray | None = None,
                      hair_facing: float | None = None):
    """Bald and hair recoloured from the views (module docstring, "Colour"): every Gaussian's
    samples (`view_samples`, hair by the renderer's visibility), their weighted mean
    (`blend_colours`), then hair no view saw filled from the nearest seen hair
    (`fill_hidden_hair`). normals: (N_bald + N_hair, 3) outward normals; keep: (N,) bool rows
    left as they are (the neck); body: (N,) bool rows that may sample a turned keyframe's body
    pixels on its head (`view_samples(body=)`, `SCALP_BODY`); scalp: (N,) bool bald rows that no
    view saw are filled from the nearest seen ones of them (`SCALP_FILL`); drop_skin_hair: hair
    the reference shows edge-on that the other keyframes see on skin is dropped
    (`EDGE_HAIR_ON_SKIN`); neck: (N,) bool bald rows of the neck, of which those no view saw
    that are not kept and not its underside are filled from the nearest ones seen or kept
    (`NECK_FILL`); bald_views: the views (in views' order) the bald rows are sampled from where
    one is not the same object as its view in `views` (a keyframe's `skin_pose`,
    `VideoViews.skin_views`): the hair rows keep `views`' samples; hidden_bald: (N,) bool bald rows
    (outside the neck) of which those no view saw, not kept, not filled as scalp, facing away
    from the reference view and not shown by its camera are filled from the nearest seen ones
    (`HIDDEN_BALD_FILL`, `HIDDEN_BALD_SHOWN`); hair_facing: the hair rows' samples weighted by
    facing as well (`view_samples(hair_facing=)`, `HAIR_FACING`), and the hair the reference
    sees at a grazing angle, little of it shown, kept with the blend's colour after the photo's
    matching (`HAIR_FACING_SHOWN`, figures["_only_others"]). Returns
    (bald, hair, figures)."""
    from avatarkit.gaussians.gaussian_set import GaussianSet

    both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    is_hair = np.zeros(len(both), bool)
    is_hair[len(bald):] = True
    samples = [view_samples(both, normals, v, hair=is_hair, body=body, hair_facing=hair_facing) for v in views]
    split = 0
    for i, b in enumerate(bald_views or []):
        if b is not views[i]:
            # the bald rows seen from the skin's pose: the union rendered from that camera (its
            # depth and alpha decide the bald discs' visibility), the hair rows left to `views`
            s, t = samples[i], view_samples(both, normals, b, hair=is_hair, body=body, hair_facing=hair_facing)
            samples[i] = Samples(np.where(is_hair, s.seen, t.seen), np.where(is_hair, s.weight, t.weight),
                                 np.where(is_hair[:, None], s.colour, t.colour))
            split += 1
    colours, seen = blend_colours(both.colors, samples, keep)
    colours, filled = fill_hidden_hair(both.means, colours, is_hair & seen, is_hair & ~seen)
    # where the reference view looks at a grazing angle or from behind
    to_ref = camera_centre(views[0].camera)[None] - np.asarray(both.means, np.float64)
    to_ref /= np.maximum(np.linalg.norm(to_ref, axis=1, keepdims=True), 1e-12)
    away = np.einsum("ij,ij->i", np.asarray(normals, np.float64), to_ref) < MIN_COS
    scalp_filled = 0
    if scalp is not None:
        # the scalp no view saw, from the scalp the views did see (`SCALP_FILL`), where the
        # reference view does not face it: what it faces keeps the photo's fill
        scalp = np.asarray(scalp, bool) & ~is_hair
        if keep is not None:
            scalp &= ~np.asarray(keep, bool)
        hidden = scalp & ~seen & away
        colours, scalp_filled = fill_hidden_hair(both.means, colours, scalp & seen, hidden)
    bald_filled = 0
    if hidden_bald is not None:
        # the rest of the bald layer no view saw, from what the views saw beside it
        # (`HIDDEN_BALD_FILL`), where the reference view does not face it; the scalp's own fill
        # and the rows kept stay as they are
        rows = np.asarray(hidden_bald, bool) & ~is_hair
        done = (np.asarray(scalp, bool) & ~seen & away) if scalp is not None else np.zeros(len(both), bool)
        if keep is not None:
            done |= np.asarray(keep, bool)
        target = rows & ~seen & away & ~done
        if target.any():
            # what the reference photo shows, if only edge-on at its outline, keeps its colour
            target &= footprint_visibility(both, views[0].camera) < float(HIDDEN_BALD_SHOWN)
        colours, bald_filled = fill_hidden_hair(both.means, colours, rows & seen, target)
    neck_filled = 0
    if neck is not None:
        # the neck no view saw, from the neck that has a colour: the views' blend or, where
        # kept, the photo's (`NECK_FILL`); not its underside, the cut end no view shows
        neck = np.asarray(neck, bool) & ~is_hair
        kept = np.zeros(len(both), bool) if keep is None else np.asarray(keep, bool)
        side = np.asarray(normals, np.float64)[:, 1] > -np.sin(np.radians(float(NECK_FILL_DOWN)))
        colours, neck_filled = fill_hidden_hair(both.means, colours, neck & (seen | kept),
                                                neck & ~seen & ~kept & side)
    on_skin = np.zeros(len(both), bool)
    if drop_skin_hair and EDGE_HAIR_ON_SKIN is not None:
        from avatarkit.recon.segment import HAIR, SKIN

        # hair the reference shows edge-on, that the keyframes facing it see as skin
        means = np.asarray(both.means, np.float64)
        skin_w = label_weights(means, samples, views, (SKIN,))
        hair_w = label_weights(means, samples, views, (HAIR,))
        on_skin = is_hair & away & (skin_w > EDGE_HAIR_ON_SKIN * (skin_w + hair_w)) & (skin_w > 0)
    seen_by = np.stack([s.seen for s in samples])                  # (V, N)
    # ... and only where the reference view looks at a grazing angle or from behind: what it
    # faces (the brows, say) the reference photo's matching colours best
    only_others = seen & ~seen_by[0] & away
    grazed_kept = 0
    if hair_facing is not None and HAIR_FACING_SHOWN is not None:
        # the hair the reference sees only along its shell, little of it shown: the facing views'
        # blend, not the photo's outline (`HAIR_FACING_SHOWN`)
        grazed = is_hair & seen & seen_by[0] & away
        if grazed.any():
            grazed &= footprint_visibility(both, views[0].camera) < float(HAIR_FACING_SHOWN)
        only_others |= grazed
        grazed_kept = int(grazed.sum())
    figures = {"seen": int(seen.sum()), "of": len(both),
               "seen_only_by_other_keyframes": int((seen & ~seen_by[0]).sum()),
               "hidden_hair_filled": int(filled), "hidden_scalp_filled": int(scalp_filled),
               "hidden_bald_filled": int(bald_filled),
               "hidden_neck_filled": int(neck_filled), "skin_pose_views": split,
               "hair_grazed_kept": grazed_kept,
               "edge_hair_on_skin_dropped": int(on_skin.sum()),
               "per_view": [int(s.seen.sum()) for s in samples],
               "hair_seen": int((is_hair & seen).sum()), "hair": int(is_hair.sum())}
    both = both.with_colors(colours)
    figures["_only_others"] = (np.asarray(both.means, np.float64)[only_others & ~on_skin], colours[only_others & ~on_skin])
    hair = hair.replace(sh=both.sh[len(bald):])
    if on_skin.any():
        hair = hair.subset(~on_skin[len(bald):])
    return bald.replace(sh=both.sh[:len(bald)]), hair, figures


@dataclass(frozen=True)
class _Posed:
    """A keyframe's camera with the rest avatar's Gaussians: what `frame_hull.recede` votes on
    (the `.gaussians` and `.camera` of a `frame_colours.FrameView`)."""

    gaussians: object
    camera: object


def recede_outline(bald, hair, views: list[View], fit):
    """The bald discs the keyframes show over the wall moved inward (`RECEDE_KEYFRAMES`): each
    view's wall is its labels' background (`frame_hull.wall_image`, `RECEDE_MARGIN`), the discs
    move along their host face's inward normal (`frame_hull.inward_normals`), `RECEDE_STEP` of a
    pixel a round. bald (N_bald, with extras["binding"]) and hair (N_hair) in the rest frame the
    views' cameras see. Returns (bald moved, figures)."""
    from avatarkit.gaussians.gaussian_set import GaussianSet
    from avatarkit.recon.bald_discs import camera_pixel
    from avatarkit.recon.segment import BACKGROUND
    from avatarkit.track import frame_hull

    nb = len(bald)
    walls = [None if v.labels is None else frame_hull.wall_image(v.labels != BACKGROUND, RECEDE_MARGIN)
             for v in views]
    if nb == 0 or "binding" not in bald.extras or sum(w is not None for w in walls) < RECEDE_MIN_FRAMES:
        return bald, {"moved": [], "total": 0}
    normals = frame_hull.inward_normals(fit.rest_vertices, fit.model.faces, bald.extras["binding"])
    rest = np.asarray(bald.means, np.float64)                     # (N_bald, 3)
    step = RECEDE_STEP * camera_pixel(views[0].camera, rest)      # metres a round
    plain_hair = hair.replace(extras={})

    def pose(offsets):
        both = GaussianSet.concat([bald.replace(means=(rest + offsets).astype(np.float32), extras={}), plain_hair])
        return [_Posed(both, v.camera) for v in views]

    movable = np.ones(nb, bool) if RECEDE_SCALP else ~_region_rows(bald, GaussianSet.empty(), fit, "scalp", every=False)[:nb]
    edge, turn = RECEDE_EDGE, RECEDE_EDGE_TURN
    if edge is not None and turn is not None:
        # session 23's quorum, and the edge rule led by the far-turned keyframes only
        turns = turned_yaws(views, rest.mean(axis=0))
        agree = RECEDE_EDGE_AGREE
        if agree is not None:
            # a turned keyframe whose silhouette disagrees with the avatar's inside does not lead
            posed = pose(np.zeros((nb, 3)))
            turns = np.array([t if w is None or t < turn or deep_disagreement(p.gaussians, p.camera, w) <= agree
                              else -1.0 for t, w, p in zip(turns, walls, posed)])
        if RECEDE_EDGE_LIKE is not None:
            # the leading keyframes vote only over the wall that does not look like the person
            walls = [sure_wall(w, v.image, v.labels != BACKGROUND, RECEDE_EDGE_LIKE) if w is not None and t >= turn
                     else w for w, v, t in zip(walls, views, turns)]
        receded = frame_hull.recede(pose, walls, normals, movable, step=step, rounds=RECEDE_ROUNDS,
                                    share=RECEDE_SHARE, quorum=RECEDE_QUORUM, min_frames=RECEDE_MIN_FRAMES,
                                    near=edge, lead=[bool(t >= turn) for t in turns],
                                    near_share=RECEDE_EDGE_SHARE, near_min_frames=RECEDE_EDGE_FRAMES,
                                    lead_rounds=RECEDE_EDGE_ROUNDS)
        receded.info["lead"] = [int(v.frame) for v, t in zip(views, turns) if t >= turn]
    else:
        receded = frame_hull.recede(pose, walls, normals, movable, step=step, rounds=RECEDE_ROUNDS,
                                    share=RECEDE_SHARE if edge is None else RECEDE_EDGE_SHARE, quorum=RECEDE_QUORUM,
                                    min_frames=RECEDE_MIN_FRAMES if edge is None else RECEDE_EDGE_FRAMES,
                                    near=edge)
    moved = bald.replace(means=(rest + receded.offsets).astype(np.float32))
    return moved, {**receded.info, "step_m": round(float(step), 6), "margin_px": RECEDE_MARGIN}


def deep_disagreement(gaussians, camera, wall: np.ndarray) -> float:
    """How far a keyframe's silhouette disagrees with the avatar's beyond the outline's band: the
    pixels of its `wall` ((H, W) int32 1s, `frame_hull.wall_image`) the render of `gaussians` at
    `camera` covers (alpha > 0.5) more than `RECEDE_EDGE_DEEP` pixels inside its own outline, per
    pixel of that outline (the covered pixels next to an uncovered one)."""
    from scipy import ndimage

    from avatarkit.render import render

    covered = np.asarray(render(gaussians, camera, (0.0, 0.0, 0.0)).alpha) > 0.5       # (H, W)
    inside = ndimage.distance_transform_edt(covered)                                   # (H, W) px to the outline
    outline = covered & ~ndimage.binary_erosion(covered, np.ones((3, 3), bool), border_value=0)
    deep = (np.asarray(wall) == 1) & (inside > float(RECEDE_EDGE_DEEP))
    return float(deep.sum()) / max(int(outline.sum()), 1)


def sure_wall(wall: np.ndarray, image: np.ndarray, person: np.ndarray, levels: float, inset: int = 3) -> np.ndarray:
    """(H, W) int32: `wall` ((H, W) int32 1s, `frame_hull.wall_image`) less the pixels whose colour
    in `image` (H, W, 3) uint8 lies within `levels` in every channel of the person's nearest to
    them, taken `inset` px inside `person` (H, W) bool (the frame blends the wall and the person in
    the pixel or two at its edge)."""
    from scipy import ndimage

    core = ndimage.binary_erosion(np.asarray(person, bool), np.ones((2 * inset + 1,) * 2, bool))
    if not core.any():
        return np.asarray(wall, np.int32)
    _, (iy, ix) = ndimage.distance_transform_edt(~core, return_indices=True)     # the nearest core pixel
    img = np.asarray(image, np.int16)
    like = (np.abs(img - img[iy, ix]) <= levels).all(axis=-1)
    return np.where(like, 0, np.asarray(wall, np.int32)).astype(np.int32)


def turned_yaws(views: list[View], centre: np.ndarray) -> np.ndarray:
    """(V,) float64 degrees: how far each view's camera is turned about the point `centre` (3,)
    (the head, in the rest frame the cameras see) from the reference view's (the first if none
    is marked), its yaw in the reference camera's axes (x right, z forward: pitch and roll left
    out), in [0, 180]."""
    ref = next((v for v in views if v.reference), views[0]).camera
    axes = np.asarray(ref.rotation, np.float64)                  # (3, 3) rest -> the reference camera
    centre = np.asarray(centre, np.float64).reshape(3)

    def yaw(camera) -> float:
        d = axes @ (np.asarray(camera.camera_center, np.float64) - centre)    # the head to the camera
        return float(np.degrees(np.arctan2(d[0], -d[2])))

    y0 = yaw(ref)
    return np.array([abs((yaw(v.camera) - y0 + 180.0) % 360.0 - 180.0) for v in views])


@dataclass
class Keyframe:
    """A keyframe as the video build hands it over: image (H, W, 3) uint8; pose (4, 4) the
    joint fit's head pose in the view frame; sharpness in [0, 1]; frame: video frame number;
    outline_pose: (4, 4) the pose the hair's outline stage measures this keyframe's silhouette
    with (`track.video_build.refine_keyframes`: registered against the draft build; None: pose);
    skin_pose: (4, 4) the pose the bald layer's colours are sampled with (registered with the
    draft's hair discounted, `track.video_build.SKIN_POSE`; None: pose). The hair keeps `pose`
    (and `outline_pose`): each layer is coloured from the pose that registers that layer."""

    image: np.ndarray
    pose: np.ndarray
    sharpness: float
    frame: int
    outline_pose: np.ndarray | None = None
    skin_pose: np.ndarray | None = None


def _row_keys(points) -> np.ndarray:
    """(N,) opaque keys of (N, 3) points, equal exactly when the float64 rows are bit for bit."""
    p = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))
    return p.view(np.dtype((np.void, p.dtype.itemsize * 3))).ravel()


def _region_rows(bald, hair, fit, region: str, every: bool) -> np.ndarray:
    """(N_bald + N_hair,) bool: the bald Gaussians whose host face has every vertex (every) or
    any vertex in the head model's `region`; none where the model has no such region or the
    bald set no binding."""
    rows = np.zeros(len(bald) + len(hair), bool)
    model = fit.model
    if region in model.regions and "binding" in bald.extras:
        inside = model.region_mask(region)[model.faces]
        faces = inside.all(axis=1) if every else inside.any(axis=1)
        rows[:len(bald)] = faces[np.asarray(bald.extras["binding"], np.int64)]
    return rows


@dataclass
class VideoViews:
    """What a video build passes to `build_avatar`: shape (S,) the joint identity (the shape the
    keyframes' poses were fitted with; the build fits the reference keyframe's own shape);
    keyframes: the reference first (its image is the portrait being built); info: figures for
    the report."""

    shape: np.ndarray
    keyframes: list[Keyframe]
    info: dict = field(default_factory=dict)
    #: the video's wall plate (`track.background_plate.Plate`) every keyframe's segmentation
    #: takes (`recon.segment`, `plate=`), or None
    plate: object = None

    def register(self, fit, image: np.ndarray, labels: np.ndarray, options=None) -> list[View]:
        """The keyframes as `View`s of the fitted rest head (`keyframe_cameras`), each other
        keyframe segmented (`recon.segment`); a keyframe whose face the portrait analysis does
        not find keeps no labels (it still gives colours) and a warning."""
        from avatarkit.errors import AvatarKitError
        from avatarkit.recon.portrait import analyze_portrait
        from avatarkit.recon.segment import segment_portrait

        ref = self.keyframes[0]
        cams = keyframe_cameras(fit.camera, pose_matrix(fit.rotation, fit.translation), ref.pose,
                                [k.pose for k in self.keyframes])
        detector = getattr(options, "face_detector", "auto")
        faces = fit.model.faces
        colours = reference_colours(image, labels) if RELABEL_KEYFRAMES else None
        views = [View(image, fit.camera, np.asarray(labels, np.int32), ref.sharpness, ref.frame, True,
                      head=head_silhouette(fit.rest_vertices, faces, fit.camera))]
        # the frames registered at the turns' ends (`track.video_build.register_turned`)
        turned_end = {int(f["frame"]) for f in self.info.get("registered", [])}
        for k, cam in zip(self.keyframes[1:], cams[1:]):
            v = View(k.image, cam, None, k.sharpness, k.frame, False,
                     head=head_silhouette(fit.rest_vertices, faces, cam))
            if k.frame in turned_end:
                v.info["turned_end"] = True
            connected = RELABEL_CONNECTED if (RELABEL_CONNECTED_IN == "all" or k.frame in turned_end) else None
            wall = plate_wall(self.plate, k.image)
            wall_coloured = wall_palette_pixels(self.plate, k.image)
            if wall_coloured is not None:
                v.info["wall_coloured"] = wall_coloured
                v.info["wall_fringe"] = self.fringes_wall()
            try:
                analysis = analyze_portrait(k.image, None, detector=detector)
                v.labels = np.asarray(segment_portrait(k.image, analysis, plate=self.plate).labels, np.int32)
                if colours is not None:
                    v.labels = relabel_head(v.labels, k.image, v.head, colours, connected=connected,
                                            wall=wall).astype(np.int32)
            except AvatarKitError as e:
                if colours is None:
                    v.info["warnings"] = [f"keyframe {k.frame}: not segmented ({e}); used for colours only"]
                else:
                    # a head turned to the profile shows no face to the portrait analysis: its
                    # head is labelled by the reference view's colours alone (`relabel_head` on
                    # an image of background: what is not the background's colour by the head
                    # is the person's)
                    v.labels = relabel_head(np.zeros(k.image.shape[:2], np.int32), k.image, v.head,
                                            colours, connected=connected, wall=wall).astype(np.int32)
            views.append(v)
        return views

    def outline_views(self, fit, views: list[View]) -> list[View]:
        """`views` (as `register` made them, in the keyframes' order) with the camera of each
        keyframe that has an `outline_pose` made from it instead, and the fitted head seen by that
        camera (`head_silhouette`: `silhouette_outside` joins it to the person mask, so a head
        left at the joint fit's pose would hold hair the registered silhouette leaves out, or
        the other way round); labels and image unchanged: they are the frame's."""
        import dataclasses

        which = [i for i, (k, v) in enumerate(zip(self.keyframes, views))
                 if k.outline_pose is not None and not v.reference]
        out = list(views)
        if not which:
            return out
        cams = keyframe_cameras(fit.camera, pose_matrix(fit.rotation, fit.translation), self.keyframes[0].pose,
                                [self.keyframes[i].outline_pose for i in which])
        for i, cam in zip(which, cams):
            v = views[i]
            head = None if v.head is None else head_silhouette(fit.rest_vertices, fit.model.faces, cam)
            out[i] = dataclasses.replace(v, camera=cam, head=head)
        return out

    def uses_skin_poses(self) -> bool:
        """Whether the bald layer takes the keyframes' `skin_pose`s (`skin_views`): not in a
        registration draft (info["draft"]) unless `SKIN_POSE_IN_DRAFTS`."""
        return bool(SKIN_POSE_IN_DRAFTS or not self.info.get("draft", False))

    def skin_views(self, fit, views: list[View]) -> list[View]:
        """`views` (as `register` made them, in the keyframes' order) with the camera of each
        keyframe that has a `skin_pose` made from it instead, and the fitted head seen by that
        camera (`View.head`, which `view_samples(body=)` reads); labels and image unchanged:
        they are the frame's. The rest (and every view where `uses_skin_poses` is False) is the
        same object as in `views`."""
        import dataclasses

        out = list(views)
        which = [i for i, (k, v) in enumerate(zip(self.keyframes, views))
                 if k.skin_pose is not None and not v.reference]
        if not which or not self.uses_skin_poses():
            return out
        cams = keyframe_cameras(fit.camera, pose_matrix(fit.rotation, fit.translation), self.keyframes[0].pose,
                                [self.keyframes[i].skin_pose for i in which])
        for i, cam in zip(which, cams):
            seen_head = views[i].head
            head = None if seen_head is None else head_silhouette(fit.rest_vertices, fit.model.faces, cam)
            out[i] = dataclasses.replace(views[i], camera=cam, head=head)
        return out

    def keep_view_colours(self, bald, hair):
        """Bald and hair with the colours `colour` gave the Gaussians only the other keyframes
        saw (not the reference view) put back: the reference photo's colour matching comes
        after the blend (`recon.pipeline`), and it reaches Gaussians the reference view sees
        only at a grazing angle or past the silhouette (the side of the jaw, the shadowed side
        of a turned head) and pulls them to the photo there, which is the background or the
        lit front. Rows are matched by their centres (the silhouette cover in between adds and
        drops Gaussians, it moves none). Only Gaussians the reference view faces at a grazing
        angle or from behind (cos < `MIN_COS`) are kept: putting back the blend's colours of
        those it faces (the brows) cost the sample avatar 0.8 dB at +45 degrees. Returns
        (bald, hair, rows restored)."""
        means, colours = getattr(self, "_only_others", (np.zeros((0, 3)), np.zeros((0, 3), np.float32)))
        if not len(means):
            return bald, hair, 0
        keys = _row_keys(means)
        order = np.argsort(keys, kind="stable")          # equal centres: the last one counts
        out, n = [], 0
        for g in (bald, hair):
            gk = _row_keys(g.means)
            at = np.searchsorted(keys[order], gk, side="right") - 1
            hit = at >= 0
            hit[hit] = keys[order[at[hit]]] == gk[hit]
            if hit.any():
                rgb = g.colors.astype(np.float32).copy()
                rgb[hit] = colours[order[at[hit]]]
                g = g.with_colors(rgb)
                n += int(hit.sum())
            out.append(g)
        return out[0], out[1], n

    def summary(self, views: list[View]) -> dict:
        return {**self.info, "views": len(views), "segmented": int(sum(v.labels is not None for v in views))}

    @staticmethod
    def neck_rows(bald, hair, fit) -> np.ndarray:
        """(N_bald + N_hair,) bool: the bald Gaussians bound to the neck (every vertex of the
        host face in the head model's "neck" region): the tracked head turns, the neck does not,
        so the keyframes' views of it are not the rest avatar's."""
        return _region_rows(bald, hair, fit, "neck", every=True)

    @staticmethod
    def scalp_rows(bald, hair, fit) -> np.ndarray:
        """(N_bald + N_hair,) bool: the bald Gaussians bound to a face of the head model with a
        vertex in its "scalp" region (`SCALP_BODY`)."""
        return _region_rows(bald, hair, fit, "scalp", every=False)

    def fills_scalp(self) -> bool:
        """Whether `colour` fills the scalp no keyframe saw (`SCALP_FILL`): not in a draft the
        video build registers its turned keyframes against (info["draft"]) unless
        `DRAFT_SCALP_FILL`."""
        return bool(SCALP_FILL and (DRAFT_SCALP_FILL or not self.info.get("draft", False)))

    def fills_hidden_bald(self) -> bool:
        """Whether `colour` fills the bald layer outside the neck that no keyframe saw
        (`HIDDEN_BALD_FILL`): not in a registration draft (info["draft"])."""
        return bool(HIDDEN_BALD_FILL and not self.info.get("draft", False))

    def recedes(self) -> bool:
        """Whether `colour` sets the bald outline in where the keyframes show it over the wall
        (`RECEDE_KEYFRAMES`, `recede_outline`): not in a registration draft (info["draft"])."""
        return bool(RECEDE_KEYFRAMES and not self.info.get("draft", False))

    def recede_views(self, fit, views: list[View]) -> list[View]:
        """The views `recede_outline` votes with: the silhouettes at the poses the hair's outline
        stage measures them with (`outline_views`: registered against the draft where the video
        build did so) when `RECEDE_OUTLINE_POSES`, else `views`."""
        return self.outline_views(fit, views) if RECEDE_OUTLINE_POSES else views

    def fringes_wall(self) -> bool:
        """Whether the body pixels beside the known wall's colours give no sample either
        (`BODY_WALL_FRINGE`): not in a registration draft (info["draft"]) unless
        `BODY_WALL_FRINGE_IN_DRAFTS`."""
        return bool(BODY_WALL_FRINGE is not None and (BODY_WALL_FRINGE_IN_DRAFTS or not self.info.get("draft", False)))

    def covers_plate(self) -> bool:
        """Whether the coverage leaves the skin pixels that continue the video's known wall
        without discs (`coverage.COVER_PLATE`): not in a registration draft (info["draft"]): the
        turned frames are registered against the drafts as they were (with them too, the mesh
        subject's keyframes on the cluttered wall moved by up to 1.8 degrees, its profile -0.17 dB)."""
        return not self.info.get("draft", False)

    def fills_neck(self) -> bool:
        """Whether `colour` fills the neck no keyframe saw (`NECK_FILL`): not in a registration
        draft (info["draft"])."""
        return bool(NECK_FILL and not self.info.get("draft", False))

    def hair_facing(self) -> float | None:
        """The knee of the facing weight on the hair's samples (`HAIR_FACING`, a cosine): None
        (the visibility alone) in a registration draft (info["draft"])."""
        return None if HAIR_FACING is None or self.info.get("draft", False) else float(HAIR_FACING)

    def drops_skin_hair(self) -> bool:
        """Whether `colour` drops the hair the reference shows edge-on that the keyframes see on
        skin (`EDGE_HAIR_ON_SKIN`): not in a registration draft (info["draft"])."""
        return bool(EDGE_HAIR_ON_SKIN is not None and not self.info.get("draft", False))

    def clears_hair(self) -> bool:
        """Whether the 3D hair segmentation lets the keyframes' clear votes take hair out
        (`recon.hair_reassign.CLEAR_SHARE`, `reassign_boundary(clear=)`): not in a registration
        draft (info["draft"]) unless `hair_reassign.CLEAR_IN_DRAFTS`."""
        from avatarkit.recon import hair_reassign

        return bool(hair_reassign.CLEAR_IN_DRAFTS or not self.info.get("draft", False))

    def colour(self, bald, hair, views: list[View], fit, sdf):
        """Bald and hair recoloured from every view (`blend_colours`), the bald rows from the
        skin views (`skin_views`); returns (bald, hair, figures); with `recedes`, the bald discs
        are first set in (`recede_outline`; with `SKIN_POSE_RECEDE` voting with the skin views)."""
        receded = None
        skin = self.skin_views(fit, views)
        if self.recedes():
            recede = self.recede_views(fit, views)
            if SKIN_POSE_RECEDE:
                # the bald outline is the skin's: its keyframes' skin poses where they have one
                recede = [s if s is not v else r for s, v, r in zip(skin, views, recede)]
            bald, receded = recede_outline(bald, hair, recede, fit)
        _, normals = sdf.query(np.concatenate([bald.means, hair.means]))
        keep = self.neck_rows(bald, hair, fit)
        neck = keep.copy() if self.fills_neck() else None
        if NECK_SHOWN is not None and keep.any():
            from avatarkit.gaussians.gaussian_set import GaussianSet

            both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
            keep = neck_kept(keep, both, views[0].camera, NECK_SHOWN)
        body = self.scalp_rows(bald, hair, fit) if SCALP_BODY else None
        scalp = self.scalp_rows(bald, hair, fit) if self.fills_scalp() else None
        hidden_bald = None
        if self.fills_hidden_bald():
            hidden_bald = np.zeros(len(bald) + len(hair), bool)
            hidden_bald[:len(bald)] = True
            hidden_bald &= ~self.neck_rows(bald, hair, fit)
        bald, hair, figures = colour_from_views(bald, hair, views, normals, keep, body, scalp,
                                                drop_skin_hair=self.drops_skin_hair(), neck=neck,
                                                bald_views=skin, hidden_bald=hidden_bald,
                                                hair_facing=self.hair_facing())
        self._only_others = figures.pop("_only_others")
        if receded is not None:
            figures["receded"] = receded
        return bald, hair, figures


__all__ = ["ALPHA_MIN", "BACKGROUND_COLOUR", "BODY_WALL", "BODY_WALL_FRINGE", "BODY_WALL_FRINGE_IN_DRAFTS", "COS_POWER", "DEPTH_TOLERANCE", "DRAFT_SCALP_FILL", "EDGE_BAND", "EDGE_HAIR_ON_SKIN", "EDGE_MARGIN",
           "HAIR_FACING", "HAIR_FACING_FLOOR", "HAIR_FACING_SHOWN", "HAIR_NEIGHBOURS", "HAIR_VISIBLE", "HIDDEN_BALD_FILL", "HIDDEN_BALD_SHOWN", "MIN_COS", "NECK_FILL", "NECK_FILL_DOWN", "NECK_SHOWN", "RECEDE_EDGE", "RECEDE_EDGE_FRAMES", "RECEDE_EDGE_AGREE", "RECEDE_EDGE_DEEP", "RECEDE_EDGE_LIKE", "RECEDE_EDGE_ROUNDS", "RECEDE_EDGE_SHARE", "RECEDE_EDGE_TURN", "RECEDE_KEYFRAMES", "RECEDE_MARGIN", "RECEDE_MIN_FRAMES", "RECEDE_OUTLINE_POSES", "RECEDE_QUORUM", "RECEDE_ROUNDS", "RECEDE_SCALP", "RECEDE_SHARE", "RECEDE_STEP", "REFERENCE_WEIGHT", "RELABEL_CONNECTED", "RELABEL_CONNECTED_IN", "RELABEL_PLATE", "RELABEL_PLATE_MATCHES", "RELABEL_PLATE_NEAR", "plate_wall", "RELABEL_KEYFRAMES", "RELABEL_REACH", "SCALP_BODY", "SCALP_FILL", "SILHOUETTE_MARGIN", "SKIN_POSE_IN_DRAFTS", "SKIN_POSE_RECEDE", "SOFT_MASK_SIGMA",
           "Keyframe", "Samples", "VideoViews", "View", "blend_colours", "camera_centre", "colour_from_views",
           "fill_hidden_hair", "footprint_visibility", "head_silhouette", "keyframe_cameras", "label_weights", "neck_kept", "person_weight", "pose_matrix", "deep_disagreement", "recede_outline", "sure_wall", "turned_yaws",
           "reference_colours", "refine_colours_views", "relabel_head", "silhouette_outside", "soft_person", "view_samples", "wall_palette_pixels"]
