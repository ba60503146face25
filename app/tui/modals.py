"""Dialogs of the operator's terminal: a confirmation before anything that moves the robot or
changes the applied parameters, and the shelving of an alarm (reason and duration)."""

from __future__ import annotations

from typing import ClassVar

from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import Button, Input, Label


class ConfirmScreen(ModalScreen[bool]):
    """Yes / no; `y` and `n` (or Escape) answer from the keyboard."""

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("y", "answer(True)", "Yes"),
        Binding("n,escape", "answer(False)", "No"),
    ]

    def __init__(self, question: str) -> None:
        super().__init__()
        self.question = question

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield Label(self.question, id="question")
            with Horizontal(classes="buttons"):
                yield Button("Yes (y)", id="yes")
                yield Button("No (n)", id="no")

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.dismiss(event.button.id == "yes")

    def action_answer(self, yes: bool) -> None:
        self.dismiss(yes)


class ShelveScreen(ModalScreen[tuple[str, float] | None]):
    """The reason and the minutes an alarm is shelved for (ISA-18.2: shelving expires)."""

    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, alarm_text: str) -> None:
        super().__init__()
        self.alarm_text = alarm_text

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield Label(f"Shelve: {self.alarm_text}")
            yield Input(placeholder="reason (required)", id="reason")
            yield Input(value="60", placeholder="minutes (1..720)", id="minutes")
            yield Label("", id="problem")
            with Horizontal(classes="buttons"):
                yield Button("Shelve", id="ok")
                yield Button("Cancel", id="cancel")

    def on_input_submitted(self) -> None:
        self._submit()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "ok":
            self._submit()
        else:
            self.dismiss(None)

    def action_cancel(self) -> None:
        self.dismiss(None)

    def _submit(self) -> None:
        reason = self.query_one("#reason", Input).value.strip()
        try:
            minutes = float(self.query_one("#minutes", Input).value)
        except ValueError:
            minutes = -1.0
        problem = self.query_one("#problem", Label)
        if not reason:
            problem.update("a reason is required")
        elif not 1.0 <= minutes <= 720.0:
            problem.update("minutes must lie in 1..720")
        else:
            self.dismiss((reason, minutes))
