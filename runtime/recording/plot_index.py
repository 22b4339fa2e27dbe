"""The ``index.html`` of a recording's figures (:mod:`.plots`): the run's summary, the
notes the figures left and the figures in their order."""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path

from .reader import Recording


def write_index(path: Path, rec: Recording, images: dict[str, Path], summary: str,
                notes: list[str], order: Sequence[str]) -> None:
    """Write ``path``: the summary, then every figure of ``images`` in ``order``."""
    title = f"ctrlunit run: {Path(rec.path).name}"
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
             "</title><style>body{font-family:sans-serif;margin:1.5em;max-width:1100px}"
             "img{max-width:100%;border:1px solid #ddd;margin:0.4em 0 1.2em}"
             "pre{background:#f6f6f6;padding:0.8em;overflow-x:auto;font-size:12px}"
             "</style></head><body>", f"<h1>{html.escape(title)}</h1>"]
    if rec.salvaged:
        parts.append(f"<p><b>Salvaged:</b> {html.escape(rec.note)}</p>")
    parts.append(f"<pre>{html.escape(summary)}</pre>")
    for n in notes:
        parts.append(f"<p><i>{html.escape(n)}</i></p>")
    for name in order:
        if name in images:
            parts.append(f"<h2>{name.replace('_', ' ')}</h2><img src='{images[name].name}' "
                         f"alt='{name}'>")
    parts.append("</body></html>")
    path.write_text("\n".join(parts), encoding="utf-8")
