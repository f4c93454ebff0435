"""``zcomp report OUT``: one self-contained HTML page for an output folder.

``collect.py`` gathers the rows (plain dicts; reads only), ``html.py`` renders the page
(inline CSS and JavaScript, the rows as one embedded JSON document), ``write.py``
links or thumbnails the images and writes ``OUT/report.html`` atomically.
"""

from __future__ import annotations

from zcomp_cli.report.collect import Collected, collect, light_summary, output_folder_problem
from zcomp_cli.report.write import DEFAULT_NAME, DEFAULT_PAGE_SIZE, write_report

__all__ = ["Collected", "DEFAULT_NAME", "DEFAULT_PAGE_SIZE", "collect", "light_summary", "output_folder_problem",
           "write_report"]
