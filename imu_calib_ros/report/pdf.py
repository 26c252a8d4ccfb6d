"""The report as a PDF (matplotlib's PdfPages): the page's text, then one page per plot.

A cheap companion of the HTML page (issue 12: "PDF too if it costs little"): the text of the
header, verdict and parameter blocks on the first pages, each embedded plot on its own page.
"""
from __future__ import annotations

import base64
import html
import io
import os
import re
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.image  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.backends.backend_pdf import PdfPages  # noqa: E402

LINES_PER_PAGE = 60


def page_text(page: str) -> list[str]:
    """The HTML page's text before its first plot, one line per paragraph, row or heading."""
    head = page.split('<img', 1)[0].split('<body>', 1)[-1]
    head = re.sub(r'</(p|tr|h1|h2|h3|li|table)>', '\n', head)
    head = re.sub(r'<br\s*/?>', ' ', head)
    head = re.sub(r'</t[dh]>', '  ', head)
    text = html.unescape(re.sub(r'<[^>]+>', '', head))
    out: list[str] = []
    for line in text.splitlines():
        line = ' '.join(line.split())
        if line:
            out += textwrap.wrap(line, 110) or ['']
    return out


def write_pdf(path: Path, page: str) -> None:
    """Write ``page`` (build_report's HTML) as a PDF at ``path``, atomically."""
    lines = page_text(page)
    imgs = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    titles = re.findall(r'<h2>([^<]*)</h2>\s*<img', page)
    tmp = path.with_name(f'.{path.name}.tmp')
    with PdfPages(tmp) as pdf:
        for k in range(0, max(len(lines), 1), LINES_PER_PAGE):
            fig = plt.figure(figsize=(8.27, 11.69))
            fig.text(0.05, 0.97, '\n'.join(lines[k:k + LINES_PER_PAGE]), va='top',
                     family='monospace', fontsize=6.5)
            pdf.savefig(fig)
            plt.close(fig)
        for i, b in enumerate(imgs):
            img = matplotlib.image.imread(io.BytesIO(base64.b64decode(b)), format='png')
            h, w = img.shape[:2]
            fig = plt.figure(figsize=(11.69, 11.69 * h / w + 0.6))
            ax = fig.add_axes((0, 0, 1, 1 - 0.6 / (11.69 * h / w + 0.6)))
            ax.imshow(img)
            ax.axis('off')
            if i < len(titles):
                fig.suptitle(html.unescape(titles[i]), fontsize=11)
            pdf.savefig(fig)
            plt.close(fig)
    os.replace(tmp, path)
