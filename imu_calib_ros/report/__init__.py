"""Self-contained HTML calibration report (matplotlib Agg PNGs embedded as base64)."""
from .builder import build_report

__all__ = ['build_report']
