"""The body: feature plans, views, values with their uncertainty and decisions (DESIGN.md
section 14). `plan` reads and checks the feature plan file, `views` finds a view and a route
per feature on the calibrated model, `values` turns a fitted feature into characteristic values
with their U95 and ISO 14253-1 decisions, `measure` measures a clamped body."""
