"""``ctrlunit plot`` and ``start --plot``: six figures and an index of a recording."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from ctrlunit.runtime.observe.summary_end import how_it_ended
from ctrlunit.runtime.recording.plots import FIGURES, plot_recording
from ctrlunit.runtime.recording.reader import read
from matplotlib.image import imread
from mcap.reader import make_reader
from runner import ctrlunit, start_json

pytestmark = pytest.mark.zenoh


@pytest.fixture(scope="module")
def lockstep(tmp_path_factory):
    """A lockstep pick & place at depth 2, recorded (zstd, the default) and plotted by
    ``start --plot``."""
    d = tmp_path_factory.mktemp("plot")
    code, rep, out = start_json(d, "--clock", "lockstep", "--pipeline", "2", "--plot",
                                str(d / "live"), tag="plot")
    assert code == 0, out
    return d, d / "live" / "run.mcap", rep


def _ink(png: Path) -> tuple[float, int]:
    """Fraction of pixels that are not the white background, and distinct colours."""
    img = imread(png)[..., :3]
    ink = float((np.abs(img - 1.0).sum(axis=2) > 0.05).mean())
    colours = len(np.unique((img * 255).astype(np.uint8).reshape(-1, 3), axis=0))
    return ink, colours


def test_start_plot_draws_every_figure_from_a_compressed_recording(lockstep):
    d, path, _ = lockstep
    live = d / "live"
    with open(path, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    assert chunks and {c.compression for c in chunks} == {"zstd"}
    for name in FIGURES:
        assert (live / f"{name}.png").read_bytes()[:4] == b"\x89PNG", name
    html = (live / "index.html").read_text()
    assert "tracking error max" in html  # the run's summary


def test_plot_writes_six_pictures_with_content_and_an_index(lockstep, tmp_path):
    _, path, _ = lockstep
    res = ctrlunit("plot", str(path), "--out", str(tmp_path / "p"), "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert set(out["images"]) == set(FIGURES) and out["notes"] == []
    html = Path(out["index"]).read_text()
    for name in FIGURES:
        png = Path(out["images"][name])
        ink, colours = _ink(png)
        # axes, ticks and text alone ink about 2 % of a figure; data more, in colour
        assert ink > 0.02 and colours > 20, (name, ink, colours)
        assert f"src='{png.name}'" in html


def test_plotted_tracking_error_is_the_reports_max(lockstep, tmp_path):
    """The error drawn (the recorded /signals/state) against the live report's (from
    the plant's samples): two accounts of the same run."""
    _, path, rep = lockstep
    plots = plot_recording(read(path), tmp_path, summary="")
    e = plots.series["tracking_error_m"]
    assert np.isfinite(e).all() and e.size == rep["cycles"]
    assert abs(float(e.max()) - rep["tracking_error_m"]["max"]) <= 1e-9
    # the figure draws the error at every recorded sample, as the summary counts it: a run
    # stopped by its tracking fault has samples after its last completed interval
    drawn = plots.series["sample_error_m"]
    assert drawn.size >= rep["cycles"] and float(drawn.max()) == rep["tracking_error_m"]["max"]
    tau = plots.series["torque_nm"]
    assert abs(float(np.abs(tau).max()) - rep["torque_nm"]["max"]) <= 1e-9


def test_cycle_range_limits_what_is_drawn_and_an_empty_range_is_named(lockstep, tmp_path):
    _, path, _ = lockstep
    plots = plot_recording(read(path), tmp_path / "a", cycles=(50, 120), summary="")
    assert plots.series["cycle"].tolist() == list(range(50, 120))
    res = ctrlunit("plot", str(path), "--out", str(tmp_path / "b"), "--cycles",
                   "900000:900010")
    assert res.returncode == 1
    assert "no interval to plot in cycles 900000:900010" in res.stderr


def test_the_first_interval_alone_plots_without_a_warning(lockstep, tmp_path):
    """A new user's ``plot --cycles 0:1`` printed matplotlib's warning of a singular
    scale: the tracking error there is zero."""
    import warnings

    _, path, _ = lockstep
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plots = plot_recording(read(path), tmp_path / "one", cycles=(0, 1), summary="")
    assert plots.series["cycle"].tolist() == [0]


def test_plot_of_a_recording_cut_off_mid_run(lockstep, tmp_path):
    """A crash leaves no footer: the salvaged part is drawn, and the page says so."""
    _, path, _ = lockstep
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[: len(data) * 3 // 5])
    res = ctrlunit("plot", str(cut), "--out", str(tmp_path / "c"), "--json")
    assert res.returncode == 0, res.stderr
    assert "salvaged" in res.stderr
    out = json.loads(res.stdout)
    assert "Salvaged" in Path(out["index"]).read_text()
    plots = plot_recording(read(cut), tmp_path / "d", summary="")
    assert 0 < plots.series["cycle"].size < len(read(path).topics["/signals/state"])


def test_freerun_plots_say_there_is_no_plant(tmp_path):
    code, _, out = start_json(tmp_path, "--clock", "freerun", "--cycles", "60", "--record",
                              str(tmp_path / "f.mcap"), tag="plotfree")
    assert code == 0, out
    plots = plot_recording(read(tmp_path / "f.mcap"), tmp_path / "p", summary="")
    assert any("freerun has no plant" in n for n in plots.notes)
    assert set(plots.images) == set(FIGURES)


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_index_html_shows_every_image_in_headless_chromium(lockstep, tmp_path):
    """Chromium loads the page and every image (naturalWidth > 0), and a screenshot of
    the page is not blank."""
    d, _, _ = lockstep
    page = (d / "live" / "index.html").resolve()
    probe = tmp_path / "probe.html"
    # the same page, with a script that writes how many images loaded into the title
    html = page.read_text().replace(
        "</body>", "<script>window.onload=()=>{const im=[...document.images];"
        "document.title='loaded '+im.filter(i=>i.complete&&i.naturalWidth>0).length+"
        "' of '+im.length;}</script></body>")
    for name in FIGURES:
        html = html.replace(f"src='{name}.png'", f"src='{(page.parent / name).as_uri()}.png'")
    probe.write_text(html)
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
             "--no-first-run", "--disable-background-networking",
             "--disable-component-update", "--disable-sync", "--allow-file-access-from-files",
             f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run([CHROMIUM, *flags, "--virtual-time-budget=5000", "--dump-dom",
                          probe.as_uri()], capture_output=True, text=True, timeout=120)
    assert f"<title>loaded {len(FIGURES)} of {len(FIGURES)}</title>" in dom.stdout, \
        dom.stderr[-2000:]
    shot = tmp_path / "page.png"
    subprocess.run([CHROMIUM, *flags, f"--screenshot={shot}", "--window-size=1100,3000",
                    page.as_uri()], capture_output=True, timeout=120)
    ink, colours = _ink(shot)
    assert ink > 0.05 and colours > 50, (ink, colours)


def test_the_spans_at_the_halved_rate_come_from_the_recorded_orders():
    """Halved at 100, back at 300, halved again at 501 and still at the end (600): two
    spans in seconds, the last one open to the end; none without orders."""
    import msgpack
    from ctrlunit.runtime.recording.plot_data import halved_spans
    from ctrlunit.runtime.recording.reader import Recording

    orders = [(100, 2), (300, 1), (501, 2)]
    rec = Recording("x.mcap", topics={"/plant/control": [
        (i, msgpack.packb({"stage": "stride", "stride": s, "start": k}))
        for i, (k, s) in enumerate(orders)] + [(9, msgpack.packb({"stage": "stop"}))]})
    spans = halved_spans(rec, 1e-3, 600)
    assert np.allclose(spans, [[0.1, 0.3], [0.501, 0.6]])
    assert halved_spans(Recording("y.mcap"), 1e-3, 600).shape == (0, 2)


@pytest.mark.parametrize("process, marked, title", [
    ("user", "stopped on request", "was stopped on request"),  # Ctrl-C, SIGTERM
    ("admission", "refused", "was refused before any motion"),
    ("central", "fault", "ended in a fault"),
    ("peripheral-2", "fault", "ended in a fault"),
])
def test_the_events_figure_says_how_the_run_ended_as_the_summary_does(process, marked, title):
    """A new user's Ctrl-C was drawn as "fault: interrupted" under a title saying the run
    ended in a fault, where the summary said "a stop asked for, not a fault"."""
    assert how_it_ended({"process": process, "message": "interrupted"}) == (marked, title)


def test_the_events_figure_marks_each_change_of_placement(tmp_path):
    """A live move (``/central/placement``), a peripheral taken over and back
    (``/faults/degraded``) are read in cycle order, a malformed record skipped, and each
    drawn on the events figure at its interval's time."""
    import msgpack
    from ctrlunit.runtime.config import RunConfig
    from ctrlunit.runtime.recording.plot_data import changes
    from ctrlunit.runtime.recording.plots import Plots, _events_figure
    from ctrlunit.runtime.recording.reader import Recording

    pack = msgpack.packb
    rec = Recording("x.mcap", topics={
        "/central/placement": [(1, pack({"from_cycle": 60, "central_blocks": ["a", "b"]}))],
        "/faults/degraded": [(2, pack({"peripheral": 2, "from_cycle": 120})),
                             (3, pack({"peripheral": 2, "from_cycle": 120,
                                       "back_from_cycle": 180})),
                             (4, pack({"peripheral": "2", "from_cycle": 9}))]})
    moved = changes(rec)
    assert moved == [(60, "placement: 2 block(s) on the central"),
                     (120, "peripheral 2 taken over"), (180, "peripheral 2 back")]
    assert changes(rec, (100, 150)) == moved[1:2] and changes(Recording("y.mcap")) == []
    rc = RunConfig.of(period=1e-3)
    n = np.arange(200)
    plots = Plots()
    _events_figure(tmp_path / "events.png", {"cycle": n, "period_s": np.full(200, 1e-3)},
                   [], None, rc, plots, moved)
    assert plots.marks == [(k * 1e-3, what) for k, what in moved]
    assert _ink(tmp_path / "events.png")[0] > 0.01 and not plots.clashes


def test_peripherals_standing_by_are_not_drawn_as_taken_over(tmp_path):
    """A new user's review: with peripheral 1 lost and 2 and 3 standing by beside it, the
    events figure drew three labels on one line over each other, the only readable one
    'peripheral 3 taken over'. A record seen again at each change counts once, one
    standing by says so, and the changes of one interval share one label."""
    import msgpack
    from ctrlunit.runtime.config import RunConfig
    from ctrlunit.runtime.recording.plot_data import changes
    from ctrlunit.runtime.recording.plots import Plots, _events_figure
    from ctrlunit.runtime.recording.reader import Recording

    def lost(k: int, **more: int) -> tuple[int, bytes]:
        why = "stands by: peripheral 1 fell silent" if k != 1 else "peripheral 1 silent"
        return 0, msgpack.packb({"peripheral": k, "from_cycle": 120, "why": why, **more})

    rec = Recording("x.mcap", topics={"/faults/degraded": [
        lost(1), lost(2), lost(3), lost(1), lost(3, back_from_cycle=150),
        lost(2, back_from_cycle=151)]})
    moved = changes(rec)
    assert moved == [(120, "peripheral 1 taken over"), (120, "peripheral 2 stands by"),
                     (120, "peripheral 3 stands by"), (150, "peripheral 3 back"),
                     (151, "peripheral 2 back")]
    plots = Plots()
    n = np.arange(200)
    _events_figure(tmp_path / "events.png", {"cycle": n, "period_s": np.full(200, 1e-3)},
                   [], None, RunConfig.of(period=1e-3), plots, moved)
    assert plots.marks[0] == (0.12, "peripheral 1 taken over; peripheral 2 stands by; "
                                    "peripheral 3 stands by")
    assert len(plots.marks) == 3
