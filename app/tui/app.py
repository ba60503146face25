"""The operator's terminal: seven panes (Overview, Measurements, Calibrations, Alarms, Devices,
Log, Bodies) over one service. Keyboard first (bindings in the footer); socket and database
work run in workers so the screen never waits; every action that moves the robot or changes the
applied parameters asks first and shows the service's answer."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, ClassVar

from rich.text import Text
from textual import work
from textual.app import App, ComposeResult
from textual.binding import BindingType
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.dom import NoScreen
from textual.screen import ModalScreen
from textual.widgets import (
    DataTable,
    Label,
    Sparkline,
    Static,
    TabbedContent,
    TabPane,
)
from textual.worker import Worker

from app.line.statedir import StateDir
from app.tui import alarm_view, history_view, keys, view
from app.tui.bodies import BodiesPane
from app.tui.body_view import TREND_N
from app.tui.client import Event, ServiceClient, ServiceUnavailable
from app.tui.history import HistoryReader
from app.tui.keys import PANE_FILTER, PANE_FOCUS, PANES, FilterInput
from app.tui.look import CSS, ISA101
from app.tui.modals import ConfirmScreen, ShelveScreen
from app.tui.tables import fill

#: what each pane shows from the database (only the visible pane's history is read and drawn)
PANE_HISTORY = {
    "overview": ("recent", "suspects"),
    "measurements": ("measurements",),
    "calibrations": ("calibrations", "applied", "maintenance"),
    "alarms": ("alarms",),
    "devices": (),
    "log": ("events",),
    "bodies": ("bodies", "charts"),
}
#: at most this many screen refreshes a second follow the service's events (a busy service
#: emits an event every few ms; one refresh shows them all)
MIN_REFRESH_S = 0.1
#: a refresh taking longer is abandoned (the next one starts over)
REFRESH_TIMEOUT_S = 10.0


class RvisTui(App[None]):
    """`RvisTui(state_dir)`: attach to the service of that state directory."""

    CSS = CSS
    TITLE = "rvis"
    BINDINGS: ClassVar[list[BindingType]] = keys.BINDINGS  # app.tui.keys: from which focus

    def __init__(self, state_dir: str | Path) -> None:
        super().__init__()
        self.state_dir = Path(state_dir)
        paths = StateDir(self.state_dir)
        self.history = HistoryReader(paths.db)
        self.client = ServiceClient(paths.socket, self._on_event, self._on_link)
        self.status: dict[str, Any] | None = None
        self.connection = (False, "connecting ...")
        self.events_seen = 0
        self._dirty = False
        self._refresher: Worker[None] | None = None
        self._shown: dict[str, list[Sequence[Any]]] = {}  # the rows each table shows
        self._alarms: list[dict[str, Any]] = []  # the Alarms table's alarms, in its order
        self._suspects: list[dict[str, Any]] = []  # the suspect intervals' table's, in its order
        #: the wall clock of the ages shown (replaced in the screenshot tests)
        self.now: Callable[[], datetime] = lambda: datetime.now(UTC)
        # nothing moves on the screen that needs no attention (ISA-101): no sliding tab
        # underline, no smooth scrolling; a pane switch is then one repaint, not a dozen
        # frames (0.42 -> 0.29 s of CPU a switch in the frozen terminal)
        self.animation_level = "none"

    # -- layout ------------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield Static("DISCONNECTED - connecting ...", id="status", classes="disconnected")
        yield Static("", id="banner")
        with TabbedContent(initial="overview"):
            with TabPane("1 Overview", id="overview"), VerticalScroll():
                yield Static("", id="overview-text")
                yield Label("Residual per sphere (recent measurements, mm):")
                yield Vertical(id="drift")
                yield Label("Suspect intervals (bodies measured then: re-measure or flag):")
                yield DataTable(id="suspects-table", cursor_type="row")
                yield Static("no suspect interval selected", id="suspect-detail")  # its bodies
            with TabPane("2 Measurements", id="measurements"), Vertical():
                yield FilterInput(
                    placeholder="/ filter by sphere (e.g. P2); Enter applies, Esc leaves",
                    id="sphere-filter",
                )
                yield DataTable(id="measurements-table", cursor_type="row")
            with TabPane("3 Calibrations", id="calibrations"), Vertical():
                yield Static("no calibration pending", id="pending-title")
                yield DataTable(id="pending", cursor_type="row")
                yield DataTable(id="calibrations-table", cursor_type="row")
                yield Label("Parameter versions (b: roll back to the selected one):")
                yield DataTable(id="versions-table", cursor_type="row")
                yield Label("Maintenance (rvis maintain: what was done to the cell):")
                yield DataTable(id="maintenance-table", cursor_type="row")
            with TabPane("4 Alarms", id="alarms"), Vertical():
                yield DataTable(id="alarms-table", cursor_type="row")
                yield Static("no alarm selected", id="alarm-detail")  # the selected one whole
            with TabPane("5 Devices", id="devices"), Vertical():
                yield DataTable(id="devices-table", cursor_type="row")
                yield Static("", id="device-errors")  # each device's last error, whole
            with TabPane("6 Log", id="log"), Vertical():
                yield FilterInput(
                    placeholder="/ filter events by text; Enter applies, Esc leaves",
                    id="log-filter",
                )
                yield DataTable(id="log-table", cursor_type="row")
            with TabPane("7 Body", id="bodies"):
                yield BodiesPane()
        yield keys.KeysFooter(compact=True, show_command_palette=False)

    def on_mount(self) -> None:
        self.register_theme(ISA101)
        self.theme = "isa101"
        columns = {
            "measurements-table": ("id", "time (UTC)", "sphere", "status", "residual mm", "note"),
            "pending": ("parameter", "unit", "current", "pending", "change", "std", "|chg|/std"),
            "calibrations-table": ("cal", "time (UTC)", "status", "version", "RMS mm", "gates"),
            "versions-table": ("version", "in force since (UTC)", "source", "cal"),
            "maintenance-table": (
                "id",
                "event",
                "from (UTC)",
                "to (UTC)",
                "by",
                "version",
                "validation mm",
            ),
            "alarms-table": (
                "id",
                "prio",
                "state",
                "raised (UTC)",
                "acked by",
                "alarm",
                "shelved",
            ),
            "devices-table": ("device", "state", "URL"),
            "log-table": ("time (UTC)", "event", "what happened"),
            "suspects-table": ("id", "from (UTC)", "to (UTC)", "size mm", "bodies", "what"),
        }
        for table_id, cols in columns.items():
            self.query_one(f"#{table_id}", DataTable).add_columns(*cols)
            self._shown[table_id] = []
        self.attach()
        self.set_interval(2.0, self.refresh_all)

    def attach(self) -> None:
        """Start the connection to the service (it reconnects by itself)."""
        self.run_worker(self.client.run(), group="client", exit_on_error=False)

    # -- data in -----------------------------------------------------------------------------
    async def _on_link(self, connected: bool, detail: str) -> None:
        self.connection = (connected, detail)
        if connected:
            self.refresh_all()
        else:
            self.status = None  # no reply, no facts: the screens say "unknown" (app.tui.view)
            self._show_status()

    async def _on_event(self, event: Event) -> None:
        self.events_seen += 1
        self.refresh_all()

    def refresh_all(self) -> None:
        """Bring the screen up to date: coalesced, never cancelled. A refresh asked for while
        one runs makes that one go round once more (an exclusive worker restarted at every
        event would never finish while the service emits faster than a refresh takes)."""
        self._dirty = True
        if self._refresher is None or self._refresher.is_finished:
            self._refresher = self._refresh_loop()

    @property
    def refreshing(self) -> bool:
        """A refresh of the screen is asked for or running (tests wait for it to settle)."""
        return self._dirty or (self._refresher is not None and not self._refresher.is_finished)

    @work(group="refresh", exit_on_error=False)
    async def _refresh_loop(self) -> None:
        while self._dirty:
            self._dirty = False
            started = time.monotonic()
            try:  # a refresh that hangs (whatever the cause) must not stop the next ones
                await asyncio.wait_for(self._refresh_once(), REFRESH_TIMEOUT_S)
            except TimeoutError:
                self.log.warning(f"screen refresh took over {REFRESH_TIMEOUT_S:g} s")
            if self._dirty:  # more events came meanwhile: one more refresh, not at once
                await asyncio.sleep(MIN_REFRESH_S - (time.monotonic() - started))

    def on_tabbed_content_tab_activated(self) -> None:
        # the newly shown pane's history, its tables filled again: rows added while the pane
        # was hidden can keep the hidden layout's column widths (the snapshot tests caught a
        # narrow header over an empty log table in about one full suite in three)
        self._shown.clear()
        self.refresh_bindings()  # "/" acts on the panes that have a filter box
        self.refresh_all()

    async def _refresh_once(self) -> None:
        """The status from the socket, shown; then the visible pane's history from the
        database (in a thread), shown."""
        if self.client.connected:
            try:
                reply = await self.client.request("status")
                self.status = reply if reply.get("ok") else self.status
            except ServiceUnavailable:
                self.status = None
        else:
            self.status = None
        self._show_status()
        sphere = self.query_one("#sphere-filter", FilterInput).value.strip() or None
        text = self.query_one("#log-filter", FilterInput).value.strip()
        wanted = PANE_HISTORY[self.pane]
        hist = await asyncio.to_thread(self._read_history, wanted, sphere, text)
        self._show_history(hist)

    @property
    def pane(self) -> str:
        """The pane shown now."""
        return self.query_one(TabbedContent).active or PANES[0]

    def _read_history(
        self, wanted: Sequence[str], sphere: str | None, text: str
    ) -> dict[str, list[dict[str, Any]]]:
        """The wanted parts of the history (PANE_HISTORY), read in a worker thread."""
        readers: dict[str, Callable[[], list[dict[str, Any]]]] = {
            "measurements": lambda: self.history.measurements(200, sphere),
            "recent": lambda: self.history.measurements(400),
            "calibrations": self.history.calibrations,
            "applied": self.history.applied,
            "alarms": self.history.alarms,
            "events": lambda: self.history.events(300, text),
            "suspects": self.history.suspects,
            "maintenance": self.history.maintenance,
            "bodies": lambda: self.history.bodies(TREND_N),
            "charts": self.history.charts,
        }
        return {key: readers[key]() for key in wanted}

    # -- data out ----------------------------------------------------------------------------
    def _show_status(self) -> None:
        connected, detail = self.connection
        status_bar = self.query_one("#status", Static)
        now = view.service_now(self.status) or self.now()
        status_bar.update(Text(view.status_line(self.status, connected, detail, now)))
        status_bar.set_class(not connected, "disconnected")
        text, cls = view.banner(self.status if connected else None)
        banner = self.query_one("#banner", Static)
        banner.update(Text(text))  # service text, never markup
        banner.set_classes(f"shown {cls}" if text else "")
        self.query_one("#overview-text", Static).update(Text(view.overview_text(self.status)))
        self._fill("devices-table", view.device_rows(self.status))
        self.query_one("#device-errors", Static).update(Text(view.device_errors(self.status)))
        self._show_pending()

    def _show_pending(self) -> None:
        pending = (self.status or {}).get("pending")
        title = self.query_one("#pending-title", Static)
        if not pending:
            unknown = self.status is None or "pending" not in self.status
            title.update(
                "pending calibration unknown (no reply from the service)"
                if unknown
                else "no calibration pending"
            )
            self._fill("pending", [])
            return
        gates = pending.get("gates") or {}
        verdict = (
            "passed" if gates.get("passed") else "FAILED: " + "; ".join(gates.get("failures", []))
        )
        title.update(
            Text(
                f"PENDING calibration {pending.get('id')}: "
                f"RMS {view.num(pending.get('rms_mm'))} mm, "
                f"held-out {view.num(pending.get('holdout_rms_mm'))} mm; gates {verdict}. "
                "a approve, x reject"
            )
        )
        self._fill("pending", view.parameter_diff_rows(pending))

    def _show_history(self, hist: dict[str, list[dict[str, Any]]]) -> None:
        """Draw the parts of the history that were read (those of the visible pane)."""
        if "measurements" in hist:
            self._fill("measurements-table", history_view.measurement_rows(hist["measurements"]))
        if "calibrations" in hist:
            self._fill("calibrations-table", history_view.calibration_rows(hist["calibrations"]))
        if "applied" in hist:
            self._fill("versions-table", history_view.version_rows(hist["applied"]))
        if "maintenance" in hist:
            self._fill("maintenance-table", view.maintenance_rows(hist["maintenance"]))
        if "alarms" in hist:
            alarms = hist["alarms"] or list((self.status or {}).get("alarms") or [])
            self._alarms = sorted(alarms, key=lambda a: a.get("id", 0), reverse=True)
            self._fill("alarms-table", alarm_view.alarm_rows(self._alarms))
            self._show_alarm_detail()
        if "events" in hist:
            self._fill("log-table", history_view.log_rows(hist["events"]))
        if "bodies" in hist:
            self.query_one(BodiesPane).show(hist["bodies"], hist["charts"], self._fill)
        if "recent" in hist:
            self._show_drift(hist["recent"])
        if "suspects" in hist:
            self._suspects = hist["suspects"]
            self._fill("suspects-table", history_view.suspect_rows(self._suspects))
            self._show_suspect_detail(self.query_one("#suspects-table", DataTable))

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        if event.data_table.id == "alarms-table":
            self._show_alarm_detail()
        elif event.data_table.id == "suspects-table":
            self._show_suspect_detail(event.data_table)

    def _show_suspect_detail(self, table: DataTable[Any]) -> None:
        """The selected suspect interval's bodies, all of them, under its table (found from
        the table: another screen, a dialog, may be on top; none while the app closes)."""
        row = table.cursor_row
        selected = self._suspects[row] if 0 <= row < len(self._suspects) else None
        try:
            screen = table.screen
        except NoScreen:  # a highlight that arrives as the app shuts down
            return
        for detail in screen.query("#suspect-detail").results(Static):
            detail.update(Text(history_view.suspect_detail(selected)))

    def _show_alarm_detail(self) -> None:
        """The selected alarm whole under the table: its text, who acknowledged it, when."""
        table: DataTable[Any] = self.query_one("#alarms-table", DataTable)
        row = table.cursor_row
        selected = self._alarms[row] if 0 <= row < len(self._alarms) else None
        self.query_one("#alarm-detail", Static).update(Text(alarm_view.alarm_detail(selected)))

    def _fill(self, table_id: str, rows: Sequence[Sequence[Any]]) -> None:
        """Replace a table's rows (unless unchanged), keeping the cursor on the same row index."""
        if list(rows) == self._shown.get(table_id):
            return
        self._shown[table_id] = list(rows)
        fill(self.query_one(f"#{table_id}", DataTable), rows)

    def _show_drift(self, recent: list[dict[str, Any]]) -> None:
        by_sphere: dict[str, list[float]] = {}
        for m in reversed(recent):
            r = m.get("residual_mm")
            if isinstance(r, int | float):
                by_sphere.setdefault(str(m.get("sphere")), []).append(float(r))
        box = self.query_one("#drift", Vertical)
        for sphere, values in sorted(by_sphere.items()):
            row_id = f"drift-{sphere}"
            rows = box.query(f"#{row_id}")
            label = f"{sphere} last {values[-1]:.3f}"
            if rows:
                row = rows.first()
                row.query_one(Label).update(label)
                row.query_one(Sparkline).data = values[-60:]
            else:
                box.mount(
                    Horizontal(
                        Label(label), Sparkline(values[-60:]), id=row_id, classes="drift-row"
                    )
                )

    # -- actions -----------------------------------------------------------------------------
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """While a dialog asks, the screen keys do nothing (its own keys answer); "/" only on
        a pane with a filter box."""
        if action in keys.SCREEN_ACTIONS and isinstance(self.screen, ModalScreen):
            return False
        if action == "filter":
            return self.pane in PANE_FILTER
        return True

    def action_show(self, pane: str) -> None:
        # the focus off the pane first: a focused widget that is hidden hands the focus to a
        # sibling in its pane, and the tabs then show that pane again (the screen keys did
        # nothing after Tab in Calibrations and Log)
        self.screen.set_focus(None)
        self.query_one(TabbedContent).active = pane
        # its table: up/down select a row at once (an alarm's text whole under the table)
        self.query_one(f"#{PANE_FOCUS[pane]}", DataTable).focus()
        self.refresh_all()  # its history now, not only when the tab's activation message comes

    def action_filter(self) -> None:
        self.query_one(f"#{PANE_FILTER[self.pane]}", FilterInput).focus()

    def on_input_submitted(self, event: FilterInput.Submitted) -> None:
        self.refresh_all()
        if isinstance(event.input, FilterInput):  # applied: back to the table
            self.query_one(f"#{PANE_FOCUS[self.pane]}", DataTable).focus()

    def on_filter_input_left(self, event: FilterInput.Left) -> None:
        self.refresh_all()  # what is in the box filters the table (at every refresh)
        self.query_one(f"#{PANE_FOCUS[self.pane]}", DataTable).focus()

    def action_pause_resume(self) -> None:
        if (self.status or {}).get("paused"):
            self._command("resume", "Resume the service? The robot will move in the next window.")
        else:
            self._command("pause", None)

    def action_reset(self) -> None:
        self._command("reset", "Reset the fault? The robot may move in the next window.")

    def action_recalibrate(self) -> None:
        self._command("recalibrate", "Start a recalibration now?")

    def action_approve(self) -> None:
        pending = (self.status or {}).get("pending")
        if not pending:
            self.notify("no calibration pending", severity="warning")
            return
        self._command(
            "approve",
            f"Apply pending calibration {pending.get('id')}?",
            calibration=pending.get("id"),
        )

    def action_reject(self) -> None:
        pending = (self.status or {}).get("pending")
        if not pending:
            self.notify("no calibration pending", severity="warning")
            return
        self._command(
            "reject", f"Reject calibration {pending.get('id')}?", calibration=pending.get("id")
        )

    def action_rollback(self) -> None:
        version = self._selected("calibrations", "versions-table")
        if version is None:
            self.notify("select a parameter version in Calibrations first", severity="warning")
            return
        self._command(
            "rollback", f"Roll the parameters back to version {version}?", version=int(version)
        )

    def action_ack(self) -> None:
        alarm = self._selected("alarms", "alarms-table")
        alarm = alarm or next((str(a["id"]) for a in view.active_alarms(self.status)), None)
        if alarm is None:
            self.notify("no alarm to acknowledge", severity="warning")
            return
        self._command("ack", None, alarm=int(alarm))

    @work(group="actions", exit_on_error=False)
    async def action_shelve(self) -> None:
        alarm = self._selected("alarms", "alarms-table")
        if alarm is None:
            self.notify("select an alarm in Alarms first", severity="warning")
            return
        answer = await self.push_screen_wait(ShelveScreen(f"alarm {alarm}"))
        if answer is not None:
            reason, minutes = answer
            await self._send("shelve", alarm=int(alarm), reason=reason, minutes=minutes)

    def _selected(self, pane: str, table_id: str) -> str | None:
        """The first cell of the selected row of a table, if its pane is the one shown (a
        hidden pane's table is not kept up to date)."""
        table: DataTable[Any] = self.query_one(f"#{table_id}", DataTable)
        if self.pane != pane or table.row_count == 0:
            return None
        return str(table.get_row_at(table.cursor_row)[0])

    @work(group="actions", exit_on_error=False)
    async def _command(self, cmd: str, question: str | None, **args: Any) -> None:
        if question is not None and not await self.push_screen_wait(ConfirmScreen(question)):
            return
        await self._send(cmd, **args)

    async def _send(self, cmd: str, **args: Any) -> None:
        try:
            reply = await self.client.request(cmd, **args)
        except ServiceUnavailable as exc:
            self.notify(str(exc), title=cmd, severity="error")
            return
        if reply.get("ok"):
            self.notify(str(reply.get("message") or "done"), title=cmd)
        else:
            self.notify(f"refused: {reply.get('error')}", title=cmd, severity="error")
        self.refresh_all()
