"""Run reports (JSON with stable keys, Markdown, HTML with images and plots), batch runs on Ray."""

from go_pipeline.reporting.run_report import REPORT_SCHEMA_ID, build_report, validate_report

__all__ = ["REPORT_SCHEMA_ID", "build_report", "validate_report"]
