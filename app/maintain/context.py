"""The maintenance procedure's Context (app/maintain/__init__.py): the commissioning's with
the event it is for."""

from __future__ import annotations

from dataclasses import dataclass

from app.commission.context import Context


@dataclass
class MaintenanceContext(Context):
    """The commissioning's Context with what the procedure is for: the event ("sensor",
    "axis", "fixture"), the axis (1..6 for "axis") and the database's maintenance record."""

    event: str = ""
    axis: int | None = None
    record_id: int | None = None

    @staticmethod
    def of(ctx: Context) -> MaintenanceContext:
        """ctx as the maintenance procedure's (every maintenance step is given one)."""
        assert isinstance(ctx, MaintenanceContext)
        return ctx
