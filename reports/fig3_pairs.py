"""placeholder"""

from __future__ import annotations

from reports.base import NotAvailable, Section
from reports.context import Context

KEY = "fig3_pairs"
TITLE = "fig3_pairs"
INTRO = ""


def generate(ctx: Context, section: Section) -> None:
    raise NotAvailable("not written yet")
