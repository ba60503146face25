"""Pure numerics of the self-calibration: the 30-parameter kinematic model of the chain
part <- base <- joints <- sensor, identification, observability, inverse kinematics and
measurement planning. Imports nothing from app/, drivers/ or fakes/."""
