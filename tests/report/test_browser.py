"""report.html as a person sees it: a real headless Chromium opens it from file://, the 3D views draw,
the videos play, and the page asks nothing of the network."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("websockets")
from tests.report._browser import CHROMIUM, Browser  # noqa: E402

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium (scripts/setup.sh installs Debian's)")


def _add_videos(run: Path) -> None:
    """Two clips where the run's filming would put them (a toy run has no simulator to film)."""
    from grt.rerun import write_video

    frames = [np.full((64, 64, 3), 40 + 5 * i, np.uint8) for i in range(30)]
    shape = json.loads((run / "summary.json").read_text())["crashshapes"][0]
    clips = []
    for name in ("nominal_seed7.mp4", f"it{shape['iteration']}_c{shape['candidate']}_seed7.mp4"):
        write_video(frames, run / "videos" / name, fps=10)
        clips.append({"file": name, "label": name[:-4], "mode": "success", "journal_mode": "success"})
    (run / "videos" / "videos.json").write_text(json.dumps({"pairs": [{"title": "rank 1", "seed": 7, "clips": clips}]}))


def test_the_report_draws_plays_and_stays_offline(run_copy, tmp_path):
    _add_videos(run_copy)
    from grt.report.html import write_report

    write_report(run_copy)
    with Browser() as b:
        b.open(run_copy / "report.html")
        views = b.js("document.querySelectorAll('canvas.grt-mesh').length")
        shapes = json.loads((run_copy / "summary.json").read_text())["crashshapes"]
        assert views == 1 + len(shapes)  # the nominal object once, not beside every rank
        # the shapes use the page's width: one row of cards as wide as the grid (was: two cards, half the page)
        widths = b.js("""(() => { const g = document.querySelector('.grid'); const cards = Array.from(g.children);
            const top = cards[0].getBoundingClientRect().top;
            const row = cards.filter(c => Math.abs(c.getBoundingClientRect().top - top) < 2);
            return [g.getBoundingClientRect().width, row.reduce((w, c) => w + c.getBoundingClientRect().width, 0),
                    row.length]; })()""")
        assert widths[2] == min(1 + len(shapes), 4) and widths[1] >= 0.85 * widths[0], widths
        drawn = b.js("Array.from(document.querySelectorAll('canvas.grt-mesh')).map(c => Number(c.dataset.drawn || 0))")
        assert all(d >= 1 for d in drawn), drawn
        # not blank: the rendered pixels of every 3D view hold more than the white background
        coloured = b.js("""Array.from(document.querySelectorAll('canvas.grt-mesh')).map(c => {
            const t = document.createElement('canvas'); t.width = c.width; t.height = c.height;
            const g = t.getContext('2d'); g.drawImage(c, 0, 0);
            const d = g.getImageData(0, 0, t.width, t.height).data; let n = 0;
            for (let i = 0; i < d.length; i += 4) if (d[i] < 235 || d[i + 1] < 235 || d[i + 2] < 235) n++;
            return n / (t.width * t.height); })""")
        assert all(f > 0.05 for f in coloured), coloured
        durations = b.js("""Promise.all(Array.from(document.querySelectorAll('video')).map(v =>
            v.readyState >= 1 ? v.duration : new Promise(ok => { v.onloadedmetadata = () => ok(v.duration);
                                                                  v.onerror = () => ok(-1); })))""")
        assert len(durations) == 2 and all(d > 0 for d in durations), durations
        b.screenshot(tmp_path / "report.png")
        assert (tmp_path / "report.png").stat().st_size > 10_000
        remote = [u for u in b.requests if not u.startswith(("file:", "data:", "about:"))]
        assert remote == [], remote


def test_the_report_reads_on_a_phone(run_copy):
    """At a phone's width nothing runs off the page sideways, the views fill it one per row, and the mesh
    preparation is a table of its figures (it was raw JSON with a literal \\u00b2)."""
    from grt.report.html import write_report

    write_report(run_copy)
    page = (run_copy / "report.html").read_text()
    assert "\\u00b2" not in page and "Mesh preparation" in page
    with Browser(width=390, height=844) as b:
        b.open(run_copy / "report.html")
        overflow = b.js("document.documentElement.scrollWidth - window.innerWidth")
        assert overflow <= 1, overflow
        views = b.js("""Array.from(document.querySelectorAll('canvas.grt-mesh')).map(c => {
            const r = c.getBoundingClientRect(); return [Math.round(r.left), Math.round(r.width)]; })""")
        assert len({left for left, _ in views}) == 1 and all(w >= 300 for _, w in views), views
        nested = b.js("document.getElementById('mesh').nextElementSibling.querySelectorAll('table.kv').length")
        assert nested >= 1, nested
