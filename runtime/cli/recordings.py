"""``ctrlunit replay``, ``report``, ``plot`` and ``export``: what a recording holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from ..config import EXIT_CONFIG
from .base import FilePath, FiniteRange, _fail, _json_safe, cli


def _cycle_range(_ctx: Any, _param: Any, value: str | None) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        a, b = value.split(":")
        lo, hi = int(a or 0), int(b) if b else 2**62
    except ValueError:
        raise click.BadParameter(f"--cycles {value!r}: expected A:B (e.g. 100:200)") from None
    if lo < 0 or hi <= lo:
        raise click.BadParameter(f"--cycles {value!r}: need 0 <= A < B")
    return lo, hi


def _culprit(rec: Any) -> str | None:
    """Which of the result record's ``live`` facts a report cannot be made with (a forged
    one of the right name, the wrong shape): the first with which alone the report and
    its summary cannot be made; None if there is none."""
    import dataclasses

    from ..observe.summary import summary
    from ..recording.recorded_report import report_from_recording

    result = rec.metadata.get("ctrlunit.result") or {}
    try:
        facts = json.loads(result.get("live") or "null")
    except ValueError:
        return None
    for key in sorted(facts) if isinstance(facts, dict) else ():
        alone = {**result, "live": json.dumps({key: facts[key]})}
        trial = dataclasses.replace(rec, metadata={**rec.metadata, "ctrlunit.result": alone})
        try:
            summary(report_from_recording(trial))
            continue
        except Exception:
            pass
        shown = repr(facts[key])
        return (f"its result record's live.{key} = "
                f"{shown if len(shown) <= 60 else shown[:57] + '...'}: not what a run writes")
    return None


def _open_recording(path: str) -> Any:
    from ..recording.reader import read
    from ..recording.recorded_config import run_config

    try:
        rec = read(path)
        run_config(rec)  # every use of it reads its configuration
    except (OSError, ValueError) as exc:
        _fail(str(exc))
    if rec.salvaged or rec.damaged:
        click.echo(f"ctrlunit: note: {rec.note}", err=True)
    return rec


@cli.command()
@click.argument("file", type=FilePath(exists=True, dir_okay=False))
@click.option("--verify", is_flag=True, help="Re-execute every block and bit-compare.")
@click.option("--cycles", "cycle_range", default=None, callback=_cycle_range,
              help="Intervals A:B only.")
@click.option("--csv", "csv_dir", type=FilePath(file_okay=False), default=None,
              help="Export the signals as CSV into DIR.")
@click.option("--rate", type=FiniteRange(min=1e-3, max=1e3), default=1.0,
              show_default=True, help="Republish speed factor.")
@click.option("--loop", is_flag=True, help="Republish in a loop.")
@click.option("--start-offset", type=FiniteRange(min=0.0), default=0.0,
              help="Start this many seconds into the recording.")
@click.option("--topics", multiple=True, help="Only these topics (e.g. /plant/command).")
@click.option("--unit", default=None, help="Unit id to republish under (default: replay-<id>).")
@click.option("--connect", multiple=True, help="Zenoh endpoint to connect to.")
@click.option("--listen", multiple=True, help="Zenoh endpoint to listen on.")
@click.option("--insecure", is_flag=True,
              help="Allow endpoints beyond this host (the recording's samples and commands "
              "go to whoever reaches them).")
@click.option("--wait-subscribers", type=FiniteRange(min=0.0, max=60.0), default=1.0,
              show_default=True, metavar="SECONDS",
              help="Wait up to this long for a subscriber to every topic before sending.")
@click.option("--max-seconds", type=float, default=None, hidden=True)
def replay(file: str, verify: bool, cycle_range: tuple[int, int] | None, csv_dir: str | None,
           rate: float, loop: bool, start_offset: float, topics: tuple[str, ...],
           unit: str | None, connect: tuple[str, ...], listen: tuple[str, ...],
           insecure: bool, wait_subscribers: float, max_seconds: float | None) -> None:
    """Replay a recording: --verify bit-compares every block; --csv exports; otherwise
    republish its messages on Zenoh at the recorded pace."""
    from ..recording import replay as rp
    from ..recording import republish

    rec = _open_recording(file)
    _check_replay_options(rec, cycle_range, start_offset, topics, unit, connect, listen,
                          insecure=insecure)
    if verify:
        n, div = rp.verify(rec, cycles=cycle_range)
        if div is not None:
            _fail(f"replay --verify: the recording diverges after {n} identical intervals: "
                  f"{div}", EXIT_CONFIG)
        if n == 0:  # a pass over nothing is no pass
            _fail("replay --verify: the recording holds no interval to verify (it ended "
                  "before its first command)", EXIT_CONFIG)
        if rec.damaged:  # what could be read verified, but the file is not what was written
            _fail(f"replay --verify: the recording is damaged; the {n} intervals before the "
                  "damage are bit-identical, the rest could not be read" if rec.salvaged else
                  f"replay --verify: the recording is damaged outside its intervals (see the "
                  f"note above); all {n} are bit-identical", EXIT_CONFIG)
        click.echo(f"verified {n} intervals: every block's outputs are bit-identical to the "
                   "recording")
    if csv_dir:  # with --verify too: each output asked for is made
        for p in republish.export_csv(rec, csv_dir, cycles=cycle_range):
            click.echo(f"wrote {p}")
    if verify or csv_dir:
        return
    from ..transport.zsession import make_config

    conf = make_config(listen=list(listen) or None, connect=list(connect) or None)
    target = unit or f"replay-{rec.config.get('unit', 'x')}"
    sent = republish.republish(rec, unit=target, rate=rate, loop=loop, start_offset=start_offset,
                        topics=list(topics) or None, cycles=cycle_range, conf=conf,
                        max_seconds=max_seconds, wait_subscribers=wait_subscribers)
    click.echo(f"republished {sent} messages under ctrlunit/{target}/")


BEYOND = ("it can be reached from other hosts, and the recording's samples and commands "
          "would go to whoever reaches it: use a loopback address or a unix socket, or "
          "--insecure")


def _check_replay_options(rec: Any, cycle_range: tuple[int, int] | None, start_offset: float,
                          topics: tuple[str, ...], unit: str | None,
                          connect: tuple[str, ...], listen: tuple[str, ...], *,
                          insecure: bool) -> None:
    """What replay's options ask of this recording, checked before anything is sent:
    intervals it holds, a start inside it, topics it has, a unit id and endpoints Zenoh
    can use, under the unit's link rule (beyond the host, or a unix socket in a folder
    others may write, only with ``--insecure``: runtime/transport/security.py)."""
    from ..transport.endpoints import check_endpoint, check_unit_id, is_socket, socket_path_taken
    from ..transport.security import reaches_beyond_host, shared_folder

    cycles = sorted(m["cycle"] for _, m in rec.decoded("/plant/command")
                    if isinstance(m.get("cycle"), int))
    note = None  # said once every option is checked: an error is one line alone
    if cycle_range is not None:
        held = f"intervals {cycles[0]} to {cycles[-1]}" if cycles else "no interval"
        if not any(cycle_range[0] <= c < cycle_range[1] for c in cycles):
            _fail(f"--cycles {cycle_range[0]}:{cycle_range[1]}: the recording holds {held}")
        if cycle_range[0] < cycles[0] or cycle_range[1] > cycles[-1] + 1:  # said, not hidden
            note = (f"--cycles {cycle_range[0]}:{cycle_range[1]} reaches past the recording, "
                    f"which holds {held}: those are taken")
    times = [t for items in rec.topics.values() for t, _ in items]
    length = (max(times) - min(times)) / 1e9 if times else 0.0
    if not (start_offset == start_offset and start_offset <= length):  # NaN fails too
        _fail(f"--start-offset = {start_offset:g} s: allowed 0 to {length:.3f} s (the "
              "recording's length)")
    for topic in topics:
        if topic not in rec.topics:
            _fail(f"--topics {topic!r}: allowed: the recording's topics "
                  f"({', '.join(sorted(rec.topics))})")
    try:
        if unit is not None:
            check_unit_id(unit)
        for option, endpoints in (("--connect", connect), ("--listen", listen)):
            for e in endpoints:
                check_endpoint(e, option=option)
                why = None if insecure else shared_folder(e) if is_socket(e) \
                    else BEYOND if reaches_beyond_host(e) else None
                if not why and option == "--listen" and is_socket(e):
                    why = socket_path_taken(e)
                if why:
                    _fail(f"{option} {e}: {why}")
    except ValueError as exc:
        _fail(f"--unit: {exc}" if "unit id" in str(exc) else str(exc))
    if note:
        click.echo(f"ctrlunit: note: {note}", err=True)


@cli.command("report")
@click.argument("file", type=FilePath(exists=True, dir_okay=False))
@click.option("--json", "as_json", is_flag=True)
@click.option("--report", "report_file", type=FilePath(dir_okay=False), default=None,
              help="Write the report as JSON.")
def report_cmd(file: str, as_json: bool, report_file: str | None) -> None:
    """Regenerate the run's report from a recording alone."""
    from ..config.outputs import output_file_error
    from ..observe.summary import summary
    from ..recording.recorded_report import report_from_recording

    if report_file and Path(report_file).resolve() == Path(file).resolve():
        _fail(f"--report {report_file}: it is the recording read: give another file")
    if (why := output_file_error(report_file, "--report")):
        _fail(why)
    rec = _open_recording(file)
    try:
        rep = report_from_recording(rec)
        text = json.dumps(_json_safe(rep)) if as_json else summary(rep)
    except (AttributeError, IndexError, KeyError, TypeError, ValueError) as exc:
        # an edited or damaged file's record: what it holds does not fit where it is read
        _fail(f"report: {file}: the recording's metadata will not do: "
              f"{exc if isinstance(exc, ValueError) else _culprit(rec) or type(exc).__name__}")
    if report_file:
        with open(report_file, "w") as fh:
            json.dump(_json_safe(rep), fh, indent=2)
    click.echo(text)


@cli.command("export")
@click.argument("file", type=FilePath(exists=True, dir_okay=False))
@click.option("--rosbag2", "rosbag2_dir", type=FilePath(), required=True, metavar="DIR",
              help="Write the ROS 2 topics as a rosbag2 directory DIR (new): metadata.yaml "
                   "and an MCAP file, for ros2 bag and the tools that read bags.")
@click.option("--json", "as_json", is_flag=True, help="Print what was written as JSON.")
def export_cmd(file: str, rosbag2_dir: str, as_json: bool) -> None:
    """Export a recording for ROS 2: /joint_states, /platform/pose, /platform/reference and
    /ctrlunit/diagnostics as a rosbag2 directory (built from the recording's own
    channels when it predates them)."""
    from ..recording.rosbag2 import export_rosbag2

    rec = _open_recording(file)
    try:
        done = export_rosbag2(rec, rosbag2_dir)
    except ValueError as exc:
        _fail(f"export: {exc}")
        return
    if as_json:
        click.echo(json.dumps({"directory": str(done.directory), "counts": done.counts,
                               "converted": done.converted, "dated": done.dated}))
        return
    if done.converted:
        click.echo(f"ctrlunit: note: {file} has no ROS 2 channels (recorded before them): "
                   "built from its own channels", err=True)
    if not done.dated:
        click.echo(f"ctrlunit: note: {file} holds no wall-clock offset (recorded before it "
                   "was kept): the bag's times are the host's monotonic clock, so bag tools "
                   "date it near 1970", err=True)
    counts = ", ".join(f"{t} {n}" for t, n in done.counts.items())
    click.echo(f"wrote {done.directory}/ (rosbag2, storage mcap): {counts} messages")


@cli.command("plot")
@click.argument("file", type=FilePath(exists=True, dir_okay=False))
@click.option("--out", "out_dir", type=FilePath(file_okay=False), default=None,
              help="Directory for the PNGs and index.html (default: FILE without .mcap, "
                   "plus -plots).")
@click.option("--cycles", "cycle_range", default=None, callback=_cycle_range,
              help="Intervals A:B only.")
@click.option("--json", "as_json", is_flag=True, help="Print what was written as JSON.")
def plot_cmd(file: str, out_dir: str | None, cycle_range: tuple[int, int] | None,
             as_json: bool) -> None:
    """Draw a recording: path against the reference, tracking error, torques, period and
    traversal histograms, deadline misses and faults on the timeline, a Gantt window;
    and an index.html that shows them with the run's summary."""
    from pathlib import Path

    from ..recording.plots import plot_recording

    rec = _open_recording(file)
    out = Path(out_dir) if out_dir else Path(file).with_suffix("").with_name(
        Path(file).stem + "-plots")
    try:
        plots = plot_recording(rec, out, cycles=cycle_range)
    except ValueError as exc:
        _fail(f"plot: {exc}")
        return
    drawn = plots.series["cycle"]
    if cycle_range and len(drawn) and (cycle_range[0] < drawn[0] or cycle_range[1] > drawn[-1] + 1):
        plots.notes.append(f"--cycles {cycle_range[0]}:{cycle_range[1]} reaches past the "
                           f"recording's intervals: drawn {int(drawn[0])} to {int(drawn[-1])}")
    data = {"out": str(out), "index": str(plots.index),
            "images": {k: str(v) for k, v in plots.images.items()}, "notes": plots.notes}
    if as_json:
        click.echo(json.dumps(data))
        return
    for n in plots.notes:
        click.echo(f"ctrlunit: note: {n}", err=True)
    click.echo(f"{len(plots.images)} figures and index.html in {out}/ (open "
               f"{plots.index})")
