"""The web player in headless Chromium (Debian's `chromium`, WebGL2 on SwiftShader), driven by
Playwright: the page's image of a frame against the CPU renderer's, the slider, and a clean
console. Slow; skipped with the reason when Chromium or Playwright is missing
(`apt-get install chromium`; `pip install playwright`, no browser download needed)."""
from __future__ import annotations

import io
import json
import os
import shutil
import urllib.parse

import numpy as np
import pytest

pytestmark = pytest.mark.slow

CHROMIUM = os.environ.get("AVATARKIT_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--no-first-run", "--disable-dev-shm-usage"]
#: PSNR (dB) of the page's frame against the CPU renderer's (SH degree 0, same camera, 256 px,
#: both as 8-bit images): measured 64 dB on frames 0 and 4 of the small sample-avatar bake
#: (SwiftShader, float accumulation; the rest is 8-bit rounding, 16-bit codes and the depth
#: sort's 16-bit keys). 45 dB leaves room for another GL's rounding and still fails on a
#: convention slip (the neighbouring frame of a slow turn already scores far lower).
PSNR_MIN_DB = 45.0


def _need_browser():
    if not os.path.exists(CHROMIUM) and not shutil.which(os.path.basename(CHROMIUM)):
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        pytest.skip("playwright is not installed (pip install playwright; it drives /usr/bin/chromium)")


@pytest.fixture(scope="module")
def browser():
    _need_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        yield b
        b.close()


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """The sample avatar (small) baked for 6 frames of a head turn, and its page."""
    _need_browser()
    from avatarkit.cli.main import main

    d = tmp_path_factory.mktemp("player")
    assert main(["avatar", "sample", "-o", str(d / "avatar"), "--n-hair", "4000", "--n-bald", "4000",
                 "--no-preview", "-q"]) == 0
    assert main(["motion", "make", "turn", "-o", str(d / "turn.npz"), "--frames", "6", "--fps", "24"]) == 0
    assert main(["bake", str(d / "avatar"), str(d / "turn.npz"), "-o", str(d / "turn.usdc"), "-q"]) == 0
    assert main(["view", str(d / "turn.usdc"), "-o", str(d / "turn.html"), "-q"]) == 0
    return d


def _open(browser, page_path, frame=0, camera=None, draw=None):
    page = browser.new_page(viewport={"width": 640, "height": 560})
    errors = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    h = {"frame": str(frame)}
    if camera is not None:
        h["camera"] = json.dumps(camera.to_dict())
    if draw is not None:
        h["draw"] = draw
    page.goto(page_path.as_uri() + "#" + urllib.parse.urlencode(h))
    page.wait_for_function("document.body.dataset.state !== 'loading'", timeout=60_000)
    status = json.loads(page.inner_text("#status") or "{}")
    assert status.get("state") == "ready", status
    return page, errors


def _canvas(page) -> np.ndarray:
    from PIL import Image

    page.evaluate("window.avatarkitPlayer.settle()")
    png = page.locator("#canvas").screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float64) / 255.0


def _cpu_image(source, frame, camera, background=(0, 0, 0)):
    from avatarkit.export.splat_frames import open_splat_frames
    from avatarkit.gaussians import GaussianSet
    from avatarkit.render import render

    src = open_splat_frames(source)
    for i, parts in enumerate(src.frames()):
        if i == frame:
            gs = GaussianSet.concat([src.rest[n].replace(means=m, quats=q, scales=s, extras={})
                                     for n, (m, q, s) in parts.items()]).with_sh_degree(0)
            return np.clip(render(gs, camera, background).rgb, 0, 1)
    raise AssertionError("frame not found")


def _psnr(a, b) -> float:
    mse = float(np.mean((np.round(a * 255) - np.round(b * 255)) ** 2)) / 255.0 ** 2
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def _camera(d, azimuth=25.0, elevation=8.0):
    from avatarkit.export.splat_frames import open_splat_frames
    from avatarkit.gaussians import GaussianSet
    from avatarkit.render import frame_camera

    rest = open_splat_frames(d / "turn.usdc").rest
    return frame_camera(GaussianSet.concat([g.replace(extras={}) for g in rest.values()]), azimuth, elevation,
                        width=256, height=256)


def test_page_matches_the_cpu_renderer(browser, baked):
    camera = _camera(baked)
    for frame, draw in ((0, "expanded"), (4, "expanded"), (4, "instanced")):  # both draw paths
        page, errors = _open(browser, baked / "turn.html", frame, camera, draw)
        got = _canvas(page)
        assert got.shape == (256, 256, 3)
        want = _cpu_image(baked / "turn.usdc", frame, camera)
        psnr = _psnr(got, want)
        print(f"frame {frame} ({draw}): PSNR {psnr:.2f} dB against the CPU renderer")
        assert psnr > PSNR_MIN_DB, psnr
        # and it is this frame's image, not just any head: the other frame scores lower
        other = _cpu_image(baked / "turn.usdc", 4 - frame, camera)
        assert _psnr(got, other) < psnr - 3
        assert errors == []
        page.close()


def test_slider_changes_the_frame(browser, baked):
    page, errors = _open(browser, baked / "turn.html", 0, _camera(baked))
    first = _canvas(page)
    # what dragging the slider does: a new value and an "input" event
    page.evaluate("""() => { const s = document.getElementById('slider'); s.value = '5';
                             s.dispatchEvent(new Event('input', { bubbles: true })); }""")
    page.wait_for_function("JSON.parse(document.getElementById('status').textContent).frame === 5")
    after = _canvas(page)
    assert json.loads(page.inner_text("#status"))["frame"] == 5
    assert "frame 6 / 6" in page.inner_text("#info")
    assert np.abs(after - first).max() > 0.2  # the head turned
    assert errors == []
    page.close()


def test_page_loads_with_no_console_error_and_plays(browser, baked):
    page, errors = _open(browser, baked / "turn.html")  # the orbit camera, window-sized canvas
    page.click("#play")
    page.wait_for_function("JSON.parse(document.getElementById('status').textContent).frame > 0", timeout=20_000)
    bench = page.evaluate("window.avatarkitPlayer.bench(3)")
    assert bench["frames"] == 3 and bench["sort_ms"] >= 0
    assert errors == []
    page.close()
