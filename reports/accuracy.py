"""placeholder"""

from __future__ import annotations

from reports.base import NotAvailable, Section
from reports.context import Context

KEY = "accuracy"
TITLE = "accuracy"
INTRO = ""


def generate(ctx: Context, section: Section) -> None:
    raise NotAvailable("not written yet")
