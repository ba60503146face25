"""`rvis maintain sensor|axis N|fixture`: a guided, resumable procedure after maintenance on a
commissioned cell (issue 41, docs/maintenance.md), between a knock the service corrects by
itself and a whole commissioning.

    sensor   a sensor replaced or re-mounted: devices -> prepare -> sensor (its calibration
             from targets) -> hand-eye (the plan's views re-aimed, the flange->sensor group
             identified on the spheres) -> acceptance (PF, PS, SD) -> workspace -> hand-over
    axis N   a motor or encoder replaced on axis N: devices -> prepare -> zero (the axis's
             zero found from one view, searched where no sphere is seen) -> re-identify (the
             views re-aimed, that joint's zero identified) -> workspace -> hand-over
    fixture  the sphere fixture renewed: devices -> prepare -> spheres (the tracker measures
             them again) -> re-identify (the views re-aimed at the spheres' new places; the
             part frame identified if the robot's measurements show it moved) -> workspace ->
             hand-over

Each step is confirmed, checked and journalled like the commissioning's (the same journal,
sequence and report: app/commission/), in `STATE_DIR/maintenance/NNNN-<event>/`, on the same
state directory: its parameter history, measurements, suspect intervals and plan stay. The
hand-over writes the next parameters version (source `maintenance`, with the procedure's
workspace validation for the service's U95), the re-aimed plan, the new sensor or sphere
places, closes the suspect interval the service opened, clears its `maintenance` alarm and
completes the maintenance record in the database; `rvis run` then starts afresh on it.
"""
