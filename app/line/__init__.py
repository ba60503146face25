"""The in-line service (`rvis run`, DESIGN.md section 6): small pieces, each testable alone.

clock         real or simulated time
settings      frozen settings with defaults (the cell file's [service] and [line] sections)
station       every device opened from its URL, with the safety guard
measure       the one piece of line code that measures one sphere
schedule      the plan's configurations cycled; the slot that fits the remaining window
cycle         one clamp window: wait -> busy -> move -> sweep -> vision -> store -> home -> done
estimate      the one estimator of the cell's state (calib.cellstate) from the version in force
jumps         what the service does with a jump it finds: named, corrected, its interval
recalib       rolling set -> identification in a worker process -> gates -> pending calibration
params_store  the applied parameters file: atomic write, numbered history, rollback
store         SQLite: schema, migrations, the only code that writes SQL
service       the state machine, alarms and the audit log
control       the Unix control socket (JSON lines)
"""
