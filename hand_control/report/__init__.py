"""``hand-suite report BAG``: an HTML page of plots computed from a recorded bag."""

from hand_control.report.build import ReportResult, build_report

__all__ = ["ReportResult", "build_report"]
