"""The state database's schema: `MIGRATIONS[k]` brings version k to k + 1 (app.line.store
applies each in its own transaction). The schema's one home; the store is the only code that
writes SQL against it."""

from __future__ import annotations

MIGRATIONS: tuple[tuple[str, ...], ...] = (
    (
        """CREATE TABLE measurements (
            id INTEGER PRIMARY KEY, t REAL NOT NULL, window INTEGER NOT NULL,
            slot INTEGER NOT NULL, target TEXT NOT NULL, q_deg TEXT NOT NULL,
            c_sensor_mm TEXT, status TEXT NOT NULL CHECK (status IN ('ok', 'rejected')),
            reason TEXT NOT NULL DEFAULT '', quality TEXT NOT NULL DEFAULT '{}',
            params_version INTEGER, residual_mm REAL)""",
        "CREATE INDEX measurements_status ON measurements (status, id)",
        """CREATE TABLE calibrations (
            id INTEGER PRIMARY KEY, t REAL NOT NULL,
            status TEXT NOT NULL CHECK (status IN ('pending', 'applied', 'rejected')),
            n_measurements INTEGER NOT NULL, first_id INTEGER, last_id INTEGER,
            rms_mm REAL, holdout_rms_mm REAL, current_holdout_rms_mm REAL,
            gates TEXT NOT NULL, reason TEXT NOT NULL, document TEXT,
            version INTEGER, decided_t REAL, decided_uid INTEGER)""",
        """CREATE TABLE applied (
            id INTEGER PRIMARY KEY, t REAL NOT NULL, version INTEGER NOT NULL,
            calibration_id INTEGER, source TEXT NOT NULL, uid INTEGER)""",
        """CREATE TABLE alarms (
            id INTEGER PRIMARY KEY, code TEXT NOT NULL, priority TEXT NOT NULL,
            message TEXT NOT NULL, state TEXT NOT NULL
                CHECK (state IN ('raised', 'acked', 'cleared', 'shelved')),
            t_raised REAL NOT NULL, t_acked REAL, acked_uid INTEGER, t_cleared REAL,
            shelved_until REAL, shelve_reason TEXT)""",
        """CREATE TABLE events (
            id INTEGER PRIMARY KEY, t REAL NOT NULL, kind TEXT NOT NULL, data TEXT NOT NULL)""",
        """CREATE TABLE actions (
            id INTEGER PRIMARY KEY, t REAL NOT NULL, uid INTEGER, cmd TEXT NOT NULL,
            args TEXT NOT NULL, ok INTEGER NOT NULL, detail TEXT NOT NULL)""",
        """CREATE TABLE schedule (
            id INTEGER PRIMARY KEY CHECK (id = 1), position INTEGER NOT NULL,
            window INTEGER NOT NULL)""",
        "INSERT INTO schedule (id, position, window) VALUES (1, 0, 0)",
    ),
    # 1 -> 2: the cell temperature [degC] when the sphere was measured (NULL: no sensor)
    ("ALTER TABLE measurements ADD COLUMN temp_c REAL",),
    # 2 -> 3: the service's decision state (app.line.service: snapshot / restore)
    (
        """CREATE TABLE service_state (
            id INTEGER PRIMARY KEY CHECK (id = 1), t REAL NOT NULL, doc TEXT NOT NULL)""",
    ),
    # 3 -> 4: suspect intervals (app.line.step): from the last trustworthy measurement before
    # a step to the apply of its correction the calibration in force was wrong
    (
        """CREATE TABLE suspect_intervals (
            id INTEGER PRIMARY KEY, t_start REAL NOT NULL, t_end REAL,
            last_good_id INTEGER, onset_id INTEGER NOT NULL, params_version INTEGER,
            size_mm REAL, group_name TEXT, text TEXT NOT NULL DEFAULT '',
            end_reason TEXT, end_version INTEGER, calibration_id INTEGER)""",
        "CREATE INDEX suspect_intervals_t ON suspect_intervals (t_start)",
    ),
    # 4 -> 5: the clamp windows with the body the PLC clamped in each (app.line.cycle
    # WindowWatch; NULL: the PLC said no body). body_id has no type: an integer body number
    # stays an integer, a serial text
    (
        "CREATE TABLE windows (id INTEGER PRIMARY KEY, t REAL NOT NULL, body_id)",
        "CREATE INDEX windows_t ON windows (t)",
    ),
    # 5 -> 6: the U95 the cell stated for each window's bodies (app.line.accuracy; NULL: none
    # stated, an older rvis or no evidence)
    ("ALTER TABLE windows ADD COLUMN u95_mm REAL",),
    # 6 -> 7: maintenance procedures (app/maintain/): what was done to the cell (event, axis),
    # when, by whom, in which folder, the versions and figures before and after
    (
        """CREATE TABLE maintenance (
            id INTEGER PRIMARY KEY, t_start REAL NOT NULL, t_end REAL,
            event TEXT NOT NULL, axis INTEGER, who TEXT NOT NULL, folder TEXT NOT NULL,
            status TEXT NOT NULL CHECK (status IN ('running', 'done')),
            version_before INTEGER, version_after INTEGER,
            before TEXT NOT NULL DEFAULT '{}', after TEXT NOT NULL DEFAULT '{}')""",
    ),
    # 7 -> 8: a procedure begun again (`rvis maintain --restart`) ends its earlier record
    # 'abandoned' (SQLite changes a CHECK only by rebuilding the table)
    (
        "ALTER TABLE maintenance RENAME TO maintenance_7",
        """CREATE TABLE maintenance (
            id INTEGER PRIMARY KEY, t_start REAL NOT NULL, t_end REAL,
            event TEXT NOT NULL, axis INTEGER, who TEXT NOT NULL, folder TEXT NOT NULL,
            status TEXT NOT NULL CHECK (status IN ('running', 'done', 'abandoned')),
            version_before INTEGER, version_after INTEGER,
            before TEXT NOT NULL DEFAULT '{}', after TEXT NOT NULL DEFAULT '{}')""",
        "INSERT INTO maintenance SELECT * FROM maintenance_7",
        "DROP TABLE maintenance_7",
    ),
    # 8 -> 9: the bodies measured (app/inspect/): per body its values by evaluation (0: as
    # measured; 1, 2, ...: computed again from the raw data with other parameters, beside the
    # earlier ones, never over them), each evaluation's reason and when its file was written
    # into the results directory (NULL: not yet), and each feature's raw data
    # (the view's joints, the cell temperature, the feature's points in the sensor frame as
    # little-endian float32 x, y, z rows); a suspect interval's bodies computed again with the
    # correction: how many, how many decisions changed, and how many could not be (measured
    # before its first moved measurement: they may precede the step)
    (
        "ALTER TABLE suspect_intervals ADD COLUMN reevaluated INTEGER",
        "ALTER TABLE suspect_intervals ADD COLUMN decisions_changed INTEGER",
        "ALTER TABLE suspect_intervals ADD COLUMN not_reevaluated INTEGER",
        """CREATE TABLE bodies (
            id INTEGER PRIMARY KEY, t REAL NOT NULL, body_id, part TEXT NOT NULL,
            window INTEGER, temp_c REAL, evaluation INTEGER NOT NULL DEFAULT 0)""",
        "CREATE INDEX bodies_t ON bodies (t)",
        """CREATE TABLE body_evaluations (
            body INTEGER NOT NULL, evaluation INTEGER NOT NULL, t REAL NOT NULL,
            params_version INTEGER, statement_u95_mm REAL, reason TEXT NOT NULL,
            suspect_id INTEGER, ok INTEGER NOT NULL, n_nok INTEGER NOT NULL,
            n_undecided INTEGER NOT NULL, n_not_measured INTEGER NOT NULL,
            decisions_changed INTEGER, exported_t REAL, PRIMARY KEY (body, evaluation))""",
        "CREATE INDEX body_evaluations_unexported ON body_evaluations (exported_t, body)",
        """CREATE TABLE body_values (
            body INTEGER NOT NULL, evaluation INTEGER NOT NULL, feature TEXT NOT NULL,
            characteristic TEXT NOT NULL, kind TEXT NOT NULL, nominal_mm REAL NOT NULL,
            lower_mm REAL NOT NULL, upper_mm REAL NOT NULL, measured_mm REAL, u95_mm REAL,
            decision TEXT NOT NULL, reason TEXT NOT NULL DEFAULT '',
            PRIMARY KEY (body, evaluation, feature, characteristic))""",
        """CREATE TABLE body_raw (
            body INTEGER NOT NULL, feature TEXT NOT NULL, q_deg TEXT NOT NULL, temp_c REAL,
            sheet BLOB, edges BLOB, refused TEXT NOT NULL DEFAULT '',
            PRIMARY KEY (body, feature))""",
    ),
    # 9 -> 10: a feature's raw data per stop (app.inspect.views: a feature the robot repeats
    # worse than its tolerance allows is measured from several stops, their fits averaged)
    (
        "ALTER TABLE body_raw RENAME TO body_raw_9",
        """CREATE TABLE body_raw (
            body INTEGER NOT NULL, feature TEXT NOT NULL, stop INTEGER NOT NULL DEFAULT 0,
            q_deg TEXT NOT NULL, temp_c REAL, sheet BLOB, edges BLOB,
            refused TEXT NOT NULL DEFAULT '', PRIMARY KEY (body, feature, stop))""",
        """INSERT INTO body_raw (body, feature, stop, q_deg, temp_c, sheet, edges, refused)
            SELECT body, feature, 0, q_deg, temp_c, sheet, edges, refused FROM body_raw_9""",
        "DROP TABLE body_raw_9",
    ),
    # 10 -> 11: an alarm's structured fields beside its text (JSON; NULL: none): the
    # maintenance need's what moved and the procedures that fit (app.line.beyond_knock), read
    # back as fields, not parsed out of the message
    ("ALTER TABLE alarms ADD COLUMN detail TEXT",),
)
