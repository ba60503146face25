"""Pure image and geometry code of the laser-line sensor: sensor model, stripe extraction,
triangulation, sphere fit, sensor calibration. Imports nothing from app/, drivers/ or fakes/."""
