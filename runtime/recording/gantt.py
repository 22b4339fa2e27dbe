"""Gantt charts of compute spans, one panel per schedule (``ctrlunit plot``, ``ctrlunit
balance --figure``, the bench's figures): the measured or predicted counterparts of the
thesis's Fig. 22-24."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

DPI = 90
"""The resolution of every figure of ctrlunit (dots per inch)."""

COLORS = {"central": "#1f77b4", "peripheral_1": "#ff7f0e", "peripheral_2": "#2ca02c",
          "peripheral_3": "#d62728", "plant": "#7f7f7f"}
"""One colour per process, in every Gantt chart of ctrlunit."""

def gantt_figure(path: Path, panels: dict[str, list]) -> None:
    """One Gantt chart per panel: spans ``(process, cycle, t0_ms, t1_ms)``, labelled with
    the cycle mod 100 (the measured or predicted counterparts of the thesis's Fig. 22-24).
    Panels without spans are left out; nothing is written if none has any."""
    panels = {k: v for k, v in panels.items() if v}
    if not panels:
        return
    fig, axes = plt.subplots(len(panels), 1, figsize=(12, 2.6 * len(panels)),
                             constrained_layout=True, squeeze=False)
    span_ms = max(b for spans in panels.values() for *_, b in spans)
    for ax, (title, spans) in zip(axes[:, 0], panels.items()):
        procs = sorted({p for p, *_ in spans}, key=lambda p: (p != "central", p))
        for y, proc in enumerate(procs):
            for p, c, a, b in spans:
                if p == proc:
                    ax.broken_barh([(a, max(b - a, 0.01))], (y - 0.4, 0.8),
                                   color=COLORS.get(p, "#999999"))
                    ax.text(a, y, str(c % 100), fontsize=6, va="center")
        ax.set_yticks(range(len(procs)), procs)
        ax.set_xlim(0, span_ms * 1.02)
        ax.set_xlabel("time (ms)")
        ax.set_title(f"Gantt chart, {title} - labels: cycle mod 100; cf. thesis Fig. 22-24",
                     fontsize=9)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


__all__ = ["COLORS", "DPI", "gantt_figure"]
