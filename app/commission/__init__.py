"""`rvis commission`: a guided, resumable sequence from an empty state directory to a cell
ready for `rvis run` (DESIGN.md section 9, docs/commissioning.md).

    devices -> stripe -> sensor -> spheres -> plan -> calibration -> acceptance -> validation
    -> workspace -> ready        (the steps' one list, with their titles: table.py)

Each step is checked against stated limits (`[commission]`, `[calibration]`) before the next
may start; its results go to `STATE_DIR/commission/` (their names: files.py) and into the
journal (journal.py), so a commissioning stopped or killed half-way continues at the first
step not yet passed. The report (commission.md, commission.json) is rewritten after every step.
`--sim` runs it on the simulated line (app/sim/commission.py) through the real drivers.
"""
