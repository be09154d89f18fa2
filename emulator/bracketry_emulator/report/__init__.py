"""Benchmark report: CSV tables, Markdown, HTML and matplotlib figures."""

from bracketry_emulator.report.write import write_report

__all__ = ["write_report"]
