"""Reports: tidy CSV tables, figures mirroring the papers, a self-contained HTML report and Markdown.

The only package that imports matplotlib, and only when a figure is drawn.

Public API: :func:`write_report`, :class:`ReportFiles`, :class:`FigureData`, :func:`ensure_writable`.
"""

from studyctl.report.build import FigureData, ReportFiles, ensure_writable, write_report

__all__ = ["FigureData", "ReportFiles", "ensure_writable", "write_report"]
