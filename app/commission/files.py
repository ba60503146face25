"""The files a commissioning writes into its folder (`STATE_DIR/commission/`; `verify/` for
`rvis sensor verify`), named once: the steps write and read them through these names, and
tests/test_state_layout.py finds them spelled nowhere else in app/. The journal and the report
(journal.json, commission.md, commission.json) and the files the last step copies into the state
directory (plan.json, sensor.toml) are the state directory's names (app/line/statedir.py).
"""

from __future__ import annotations

from app.line.statedir import PLAN_NAME, SENSOR_NAME

# written by each step (see app/commission/table.py for the steps)
STRIPE_FILE = "stripe.json"  # stripe: the exposures tried and the one chosen
STRIPE_IMAGE_FILE = "stripe.png"  # stripe: the camera's image at the chosen exposure
SENSOR_DATA_DIR = "sensor-data"  # sensor: the targets captured now (CALIB_DIR layout)
SENSOR_FILE = SENSOR_NAME  # sensor: the sensor calibration (copied by the last step)
TRACKER_EXPORT_FILE = "tracker-export.csv"  # spheres: the tracker's export as given
TARGETS_FILE = "targets.csv"  # spheres: the sphere positions in the part frame
PRECALIBRATION_MEASUREMENTS_FILE = "precalibration_measurements.csv"  # precalibration
PRECALIBRATION_PARAMS_FILE = "precalibration_params.json"  # precalibration: the plan's model
PLAN_FILE = PLAN_NAME  # plan: the measurement plan (copied by the last step)
CALIBRATION_MEASUREMENTS_FILE = "calibration_measurements.csv"  # calibration
CALIBRATION_TARGETS_FILE = "calibration_targets.csv"  # calibration
PARAMS_FILE = "params.json"  # calibration: the parameters that passed the gates
PARAMS_REJECTED_FILE = "params-rejected.json"  # calibration: the ones that did not
ACCEPTANCE_FILE = "acceptance.csv"  # acceptance: PF, PS per position
VALIDATION_MEASUREMENTS_FILE = "validation_measurements.csv"  # validation
VALIDATION_ERRORS_FILE = "validation_errors.csv"  # validation
WORKSPACE_ERRORS_FILE = "workspace_errors.csv"  # workspace
# `rvis maintain` (app/maintain/) in its procedure's folder, besides the names above
PARAMS_BEFORE_FILE = "params-before.json"  # prepare: the version in force before
TARGETS_BEFORE_FILE = "targets-before.csv"  # prepare: the spheres' places before
MAINTENANCE_MEASUREMENTS_FILE = "maintenance_measurements.csv"  # the re-aimed views' measurements
