"""``python main.py gallery`` on a small grid (2 terrains x 2 integrators, 1 s, 320x240, 4^3 cube):
the page, every video it links (playable, right frame count), the page in headless Chromium, and a
failed task's cell and exit status."""
import contextlib
import io
import json
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import urlparse

import pytest

from taichi_soft import cli
from browser import Browser

HERE = Path(__file__).resolve().parent
TERRAINS, INTEGRATORS = ["plane", "sphere"], ["semi_implicit_euler", "midpoint"]
COLUMNS = INTEGRATORS + ["compare"]
FPS, DURATION = 30, 1.0  # the shipped scenes' render.fps; frames at t = 0, 1/30, ..., 1 s
SMALL = ["--terrains", ",".join(TERRAINS), "--integrators", ",".join(INTEGRATORS), "--duration", str(DURATION),
         "--resolution", "320x240", "--set", "body.0.n=4"]


def run_main(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def gallery(tmp_path_factory):
    out = tmp_path_factory.mktemp("gallery")
    code, stdout, stderr = run_main(["gallery", *SMALL, "--out", str(out), "--workers", "2"])
    assert code == 0, stderr + stdout
    return out, stdout


class Page(HTMLParser):
    """Links (href, src), video sources, figure ids and their text from the gallery page."""

    def __init__(self):
        super().__init__()
        self.links, self.videos, self.cells, self._cell = [], [], {}, None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        for k in ("href", "src"):
            if a.get(k):
                self.links.append(a[k])
        if tag == "video":
            self.videos.append(a["src"])
        if tag == "figure":
            self._cell = a["id"]
            self.cells[self._cell] = ""

    def handle_endtag(self, tag):
        if tag == "figure":
            self._cell = None

    def handle_data(self, data):
        if self._cell:
            self.cells[self._cell] += data


def parse(out: Path) -> Page:
    page = Page()
    page.feed((out / "index.html").read_text(encoding="utf-8"))
    return page


def test_page_links_are_relative_and_every_one_resolves(gallery):
    out, stdout = gallery
    page = parse(out)
    assert "page: " in stdout and "6 of 6 videos" in stdout
    assert sorted(page.videos) == sorted(f"{t}_{c}.mp4" for t in TERRAINS for c in COLUMNS)
    for link in page.links:
        u = urlparse(link)
        assert not u.scheme and not u.netloc and not link.startswith("/"), f"not a relative link: {link}"
        assert (out / u.path).is_file(), f"broken link: {link}"
    assert json.loads((out / "gallery.json").read_text())["terrains"] == TERRAINS
    assert not list(out.glob(".*")), "temporary files left behind"


def test_captions_say_dt_stiffness_divergence_energy_and_wall_time(gallery):
    out, _ = gallery
    page = parse(out)
    assert sorted(page.cells) == sorted(f"{t}-{c}" for t in TERRAINS for c in COLUMNS)
    html = (out / "index.html").read_text()
    assert html.count("<svg") == len(TERRAINS) * len(INTEGRATORS)  # one energy plot per run
    for t in TERRAINS:
        for c in INTEGRATORS:
            text = page.cells[f"{t}-{c}"]
            # 1 s of a drop from 9 m: nothing diverges, the scene's dt and stiffness are shown
            for part in ("dt = 0.001 s", "k = 2000 N/m", "did not diverge", "final energy", "wall time", "31 frames"):
                assert part in text, (t, c, part, text)
        assert "all integrators at dt = 0.001 s" in page.cells[f"{t}-compare"]


def test_every_video_is_playable_with_the_right_frame_count(gallery):
    import imageio.v3 as iio

    out, _ = gallery
    for t in TERRAINS:
        for c in COLUMNS:
            frames = iio.imread(out / f"{t}_{c}.mp4")
            size = (480, 640) if c == "compare" else (240, 320)
            assert frames.shape == (round(DURATION * FPS) + 1, *size, 3), (t, c, frames.shape)
            assert frames[0].std() > 5, "a blank frame"


# The layout and the videos' state, as the page has them now.
PROBE = """(function () {
  var rect = function (e) { var r = e.getBoundingClientRect(); return {x: r.left, y: r.top, w: r.width, h: r.height}; };
  var cells = Array.prototype.map.call(document.querySelectorAll("figure.cell"), function (f) {
    var v = f.querySelector("video"); return {id: f.id, box: rect(f), video: v ? rect(v) : null}; });
  var videos = Array.prototype.map.call(document.querySelectorAll("video"), function (v) {
    return {src: v.getAttribute("src"), ready: v.readyState, w: v.videoWidth, h: v.videoHeight,
            duration: v.duration, error: v.error ? v.error.code : null}; });
  return {cells: cells, videos: videos};
})()"""
EVERY_VIDEO_SETTLED = "Array.prototype.every.call(document.querySelectorAll('video'), v => v.error || v.readyState >= 2)"


def test_page_in_headless_chromium_lays_out_the_grid_and_loads_the_videos(gallery):
    import imageio.v3 as iio
    import numpy as np

    out, _ = gallery
    with Browser() as browser:
        browser.open((out / "index.html").as_uri())
        state = browser.wait_for(EVERY_VIDEO_SETTLED, PROBE)
        image = iio.imread(browser.screenshot())[..., :3].astype(float)
    for v in state["videos"]:
        assert v["error"] is None and v["ready"] >= 2, f"video did not load in Chromium: {v}"
        assert (v["w"], v["h"]) == ((640, 480) if "compare" in v["src"] else (320, 240)), v
        assert abs(v["duration"] - DURATION) < 0.1, v
    cells = {c["id"]: c for c in state["cells"]}
    for r, t in enumerate(TERRAINS):  # rows terrains, columns integrators, left to right, no overlap
        row = [cells[f"{t}-{c}"]["box"] for c in COLUMNS]
        assert all(abs(b["y"] - row[0]["y"]) < 2 for b in row), row
        assert all(a["x"] + a["w"] <= b["x"] for a, b in zip(row, row[1:])), row
        assert all(b["w"] > 150 for b in row), row
        if r:
            above = cells[f"{TERRAINS[r - 1]}-{COLUMNS[0]}"]["box"]
            assert row[0]["y"] >= above["y"] + above["h"], "rows overlap"
    for c in state["cells"]:  # each video's box in the screenshot shows a picture, not a blank
        b = c["video"]
        x0, y0 = int(b["x"]) + 2, int(b["y"]) + 2
        crop = image[y0:min(y0 + int(b["h"]) - 4, image.shape[0]), x0:x0 + int(b["w"]) - 4]
        assert crop.size and crop.std() > 10 and np.abs(crop - crop.mean(axis=(0, 1))).max() > 40, c["id"]


def test_a_failed_task_gets_a_cell_and_a_non_zero_exit(tmp_path, monkeypatch):
    """Both of one terrain's tasks replaced by one that raises: retried once, reported, exit 5."""
    from taichi_soft import gallery
    from taichi_soft.tasks import Task

    real = gallery.build_tasks
    monkeypatch.setenv("PYTHONPATH", str(HERE))
    monkeypatch.setattr(gallery, "build_tasks", lambda plan, dts: [
        Task(t.key, "task_helpers:fail", {"message": f"broken {t.key}"}) for t in real(plan, dts)])
    code, stdout, stderr = run_main(["gallery", "--terrains", "plane", "--integrators", "rk4", "--duration", "0.1",
                                     "--out", str(tmp_path), "--workers", "2"])
    assert code == cli.EXIT_TASKS_FAILED
    assert "task plane/rk4 FAILED after 2 attempts" in stderr and "broken plane/rk4" in stderr
    assert "task plane/compare FAILED" in stderr and "0 of 2 videos" in stdout
    cells = parse(tmp_path).cells
    assert "broken plane/rk4" in cells["plane-rk4"] and "broken plane/compare" in cells["plane-compare"]
    assert not list(tmp_path.glob("*.mp4"))


def test_bad_gallery_input_exits_2_before_any_work(tmp_path):
    for argv, text in ((["--terrains", "moon"], "unknown scene 'moon'"), (["--integrators", "euler9"], "euler9"),
                       (["--resolution", "321x240"], "even"), (["--set", "body.0.n=0"], "body.0.n"),
                       (["--duration", "-1"], "positive")):
        code, _, err = run_main(["gallery", *argv, "--out", str(tmp_path / "g")])
        assert code == 2 and text in err and len(err.strip().splitlines()) == 1, (argv, err)
    assert not (tmp_path / "g").exists() or not any((tmp_path / "g").iterdir())


# -- every element of a card stays inside it, at ordinary window widths ---------------------------
# Every element that pokes out of its card, the cards, the page's width and the cards' error notes.
BOXES = """(function () {
  var out = [];
  document.querySelectorAll("figure.cell").forEach(function (f) {
    var c = f.getBoundingClientRect();
    f.querySelectorAll("*").forEach(function (e) {
      var r = e.getBoundingClientRect();
      if (r.width === 0 && r.height === 0) return;
      if (r.left < c.left - 0.5 || r.right > c.right + 0.5 || r.top < c.top - 0.5 || r.bottom > c.bottom + 0.5)
        out.push({cell: f.id, tag: e.tagName, left: r.left, right: r.right, card: [c.left, c.right]});
    });
  });
  return {cells: document.querySelectorAll("figure.cell").length, outside: out,
          page: document.documentElement.scrollWidth, failed: document.querySelectorAll("p.failed").length};
})()"""


def _full_width_page() -> str:
    """The page of a full gallery (4 terrains x every integrator + compare), from made-up results:
    the layout, not the runs, is under test (videos are absent; the page says so in each card)."""
    from taichi_soft.gallery import Plan, page_html
    from taichi_soft.sim.integrators import names

    plan = Plan(["plane", "tilted_plane", "sphere", "bowl"], names(), None, (640, 360), None, [], Path("."))
    energy = [(0.01 * k, 88000.0 - 30.0 * k + (5000.0 if k == 40 else 0.0)) for k in range(200)]
    cells = {}
    for t in plan.terrains:
        for c in plan.integrators:
            summary = {"dt": 0.001, "diverged": c == "explicit_euler", "diverged_at": 1.2345 if c == "explicit_euler" else None,
                       "final": {"total_energy": -123456.789}, "wall_seconds": 12.3}
            cells[f"{t}/{c}"] = {"video": f"{t}_{c}.mp4", "result": {
                "summary": summary, "stiffness": "2000 N/m", "frames": 151, "energy": energy}}
        tiles = [{"integrator": c, "diverged_at": None, "final_energy": -12345.678} for c in plan.integrators]
        cells[f"{t}/compare"] = {"video": f"{t}_compare.mp4", "result": {"dt": 0.001, "frames": 151, "tiles": tiles}}
    return page_html(plan, cells, 321.0)


@pytest.mark.parametrize("width", [1280, 1920])
def test_no_element_leaves_its_card_at_ordinary_widths(tmp_path, width):
    """The energy plots were fixed 220 px SVGs: at 1400 px they spilled into the next column. The
    layout is measured once every card says its video is missing, as a reader would see it."""
    page = tmp_path / "index.html"
    page.write_text(_full_width_page(), encoding="utf-8")
    with Browser(width=width) as browser:
        browser.open(page.as_uri())
        state = browser.wait_for("document.querySelectorAll('p.failed').length === "
                                 "document.querySelectorAll('figure.cell').length", BOXES)
    from taichi_soft.sim.integrators import names

    cards = 4 * (len(names()) + 1)  # every terrain x (every integrator and the compare mosaic)
    assert state["cells"] == cards and state["failed"] == cards  # each card says its video is missing
    assert state["outside"] == []
    assert state["page"] <= width  # the columns fit: no sideways scrolling


def test_each_integrator_gets_a_step_it_takes_on_the_default_scenes():
    """The gallery's default step: the scene's for explicit methods stable at it (velocity Verlet
    included: its linear stability limit on the default cube is above the scenes' 1 ms), and a
    frame-sized step for the implicit solvers; --dt overrides them all."""
    from taichi_soft.gallery import IMPLICIT_DT, run_dt
    from taichi_soft.sim.integrators import linear_stability as ls
    from taichi_soft.sim.scene import load_scene
    from taichi_soft.sim.simulation import build_world

    assert run_dt(1e-3, "semi_implicit_euler", None) == 1e-3
    assert run_dt(1e-3, "implicit_euler", None) == IMPLICIT_DT
    assert run_dt(1e-3, "velocity_verlet", 2e-3) == 2e-3
    model, _ = build_world(load_scene("plane").data)
    w2, ratios = ls.scene_modes(model)
    assert run_dt(1e-3, "velocity_verlet", None) == 1e-3 < ls.stable_limit("velocity_verlet", w2, ratios)


def test_error_estimate_reaches_the_run_tasks_and_their_captions(tmp_path, monkeypatch):
    """``gallery --error-estimate``: the plan asks for it, each single-run task (not the mosaics)
    estimates its run and draws it in the video's overlay, and the caption shows the estimate. The
    task runs in this process with its video writer left out (the videos are another test's)."""
    import html

    from taichi_soft import gallery, runtime
    from taichi_soft.render import recorder
    from taichi_soft.sim import error_estimate as ee

    class Planned(Exception):
        pass

    plans = []

    def stop(plan, executor, scene_dts):
        plans.append(plan)
        raise Planned

    monkeypatch.setattr(gallery, "run_gallery", stop)
    with pytest.raises(Planned):
        run_main(["gallery", "--terrains", "free_float", "--integrators", "velocity_verlet", "--duration", "0.1",
                  "--set", "body.0.n=3", "--error-estimate", "--out", str(tmp_path / "g"), "--workers", "1"])
    plan = plans[0]
    assert plan.error_estimate
    tasks = gallery.build_tasks(plan, {"free_float": 1e-3})
    run_task = next(t for t in tasks if t.fn.endswith(":render_run"))
    assert run_task.kwargs["error_estimate"] and all("error_estimate" not in t.kwargs for t in tasks if t is not run_task)

    legends = []

    class Recorder:  # what render_run needs of a FrameRecorder, without rendering
        def __init__(self, sim, options):
            legends.append(options.legend)
            self.video, self.frames = options.video, 0

        def __call__(self, sim):
            self.frames += 1

        def finish(self):
            self.video.write_bytes(b"")

        def abort(self):
            pass

    monkeypatch.setattr(runtime, "init", lambda *a, **k: None)  # conftest's runtime is running
    monkeypatch.setattr(recorder, "FrameRecorder", Recorder)
    res = gallery.render_run(**run_task.kwargs)
    est = res["error_estimate"]
    assert est["dts"] == [1e-3, 5e-4, 2.5e-4] and est["shape_error"] > 0
    assert legends == [(ee.legend(est),)]
    cells = {"free_float/velocity_verlet": {"video": "a.mp4", "result": res, "error": None},
             "free_float/compare": {"video": "b.mp4", "result": None, "error": "not run (interrupted)"}}
    page = gallery.page_html(plan, cells, 1.0)
    assert html.escape(ee.legend(est)) in page and "each run with its error estimate" in page
