"""Mismatch diagnosis: locate, name the missing physics, refit, report."""

from .mechanisms import MECHANISMS as MECHANISMS
from .select import diagnose as diagnose, to_json as to_json
from .report import write_report as write_report
