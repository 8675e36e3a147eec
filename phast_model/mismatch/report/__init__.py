"""The report stage: the :class:`~.document.Report` every analysis returns, and writing it to a folder.

* :mod:`.document`: the :class:`~.document.Report` data, its report.json view (docs/mismatch.md schema), its
  plain-language summary and its markdown (report.md);
* :mod:`.html`: report.html, one self-contained page (tables as HTML, plots embedded as data URIs);
* :mod:`.plots`: the PNG plots (residual map, held-out fit, energy decay, friction curve);
* :mod:`.files`: safe writes: a report folder is written aside and swapped in, and only a new, empty or previous
  report folder is ever replaced;
* :mod:`.mjcf_answer`: for a MuJoCo model file, the answer in the model's own attributes (``calibrated.xml``, one
  more row of the held-out fit table).
"""

from .document import Report, markdown, summary_text, write_report
from .files import CALIBRATED_MODEL, REPORT_FILES, check_writable, is_report_dir
from .html import html_page, markdown_to_html

__all__ = ["CALIBRATED_MODEL", "REPORT_FILES", "Report", "check_writable", "html_page", "is_report_dir", "markdown",
           "markdown_to_html", "summary_text", "write_report"]
