"""The look of the operator's terminal (ISA-101): a quiet grey screen; the only colours are
the alarm priorities (and error notifications), each with its text as well."""

from __future__ import annotations

from textual.theme import Theme

#: ISA-101: a quiet grey screen; the only colours are the alarm priorities (and error toasts)
ISA101 = Theme(
    name="isa101",
    primary="#8a8a8a",
    secondary="#767676",
    accent="#9e9e9e",
    warning="#ffaf00",
    error="#d70000",
    success="#8a8a8a",
    foreground="#e4e4e4",
    background="#3a3a3a",
    surface="#444444",
    panel="#4e4e4e",
    dark=True,
)

CSS = """
Screen { background: #3a3a3a; color: #d7d7d7; }
#status { height: auto; background: #4e4e4e; color: #ffffff; padding: 0 1; }
#status.disconnected { background: #5f005f; color: #ffffff; text-style: bold; }
#banner { height: auto; padding: 0 1; display: none; }
#banner.shown { display: block; }
.alarm-high { background: #d70000; color: #ffffff; text-style: bold; }
.alarm-medium { background: #ffaf00; color: #000000; text-style: bold; }
.alarm-low { background: #5f87af; color: #000000; }
DataTable { background: #3a3a3a; height: 1fr; }
TabbedContent { height: 1fr; }
#overview-text { height: auto; }
.drift-row { height: 1; }
.drift-row Label { width: 22; }
.drift-row Sparkline { width: 1fr; }
#pending { height: auto; max-height: 50%; }
#devices-table { height: auto; max-height: 50%; }
#device-errors { height: auto; border-top: solid #8a8a8a; padding: 0 1; }
#alarm-detail { height: auto; max-height: 6; border-top: solid #8a8a8a; padding: 0 1; }
#suspect-detail { height: auto; max-height: 4; padding: 0 1; }
#maintenance-table { height: auto; max-height: 4; }
#body-head { height: auto; }
#body-trend { height: auto; }
/* the selected characteristic reversed: seen on a row in its decision's colour too */
#bodies-table > .datatable--cursor { text-style: bold reverse; }
.dialog { width: 70; height: auto; border: solid #8a8a8a; background: #4e4e4e; padding: 1; }
ModalScreen { align: center middle; }
.buttons { height: auto; }
Input { background: #4e4e4e; }
Sparkline > .sparkline--max-color { color: #e4e4e4; }
Sparkline > .sparkline--min-color { color: #808080; }
FooterKey .footer-key--key { color: #ffffff; background: #5f5f5f; }
"""
