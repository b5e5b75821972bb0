"""Mismatch diagnosis: locate, name the missing physics, refit, report."""

from .mechanisms import MECHANISMS as MECHANISMS
from .report import write_report as write_report
from .select import diagnose as diagnose
from .select import to_json as to_json
from .loop import diagnose_loop as diagnose_loop
from .loop import next_step as next_step
