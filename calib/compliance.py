"""The compliance- and temperature-aware model: the rigid chain plus gravity deflection of J2
and J3 and thermal growth of the arm lengths.

Gravity deflection (static, linear joint springs). The torque of a weight W at point b about
joint j's axis (unit z_j through o_j) is W ((b - o_j) x down) . z_j. Masses of a real arm are
rarely known, so the model lumps compliance x weight into coefficients [rad/m] on geometric
levers [m] computed from the rigid chain (o2, o3 on the J2/J3 axes, w the wrist centre,
f the flange; lever(a, b, z) = ((b - a)/1000 x down) . z):

    dphi2 = c2_upper lever(o2, o3, z2) + c2_fore lever(o3, w, z2) + c2_payload lever(w, f, z2)
    dphi3 = c3_fore lever(o3, w, z3) + c3_payload lever(w, f, z3)

A point mass model (upper arm m_u at mid-arm, forearm m_f at mid-forearm, payload m_p at the
flange, joint compliance k_j) gives c2_upper = k2 g (m_u/2 + m_f + m_p), c2_fore = k2 g
(m_f/2 + m_p), c3_fore = k3 g (m_f/2 + m_p), c_j_payload = k_j g m_p; the payload terms are
tiny (the wrist-flange lever is ~0.2 m) and are configured from the payload, not identified.
`down` is -z of the base frame (the robot stands level).

Thermal growth: every arm length (a_i, d_i and the J2 height above the floor mount,
`base_height_mm`) scales by s = 1 + expansion_per_k (T - reference_temp_c). `fk` applies it
exactly for one temperature; `points_part` (per-measurement temperatures) to first order,
P(T) = P + (s - 1) G with G = sum_k L_k dP/dL_k + h z_base; the neglected second order is
below 1e-4 mm for 20 K.

Jacobian: the new columns are analytic (compliance: dP/dphi_j times its lever; expansion:
(T - T_ref) G). The geometric columns are the rigid ones at the deflected angles; their
coupling through the levers and the thermal term is second order (|c| L ~ 4e-5) and left out
(Levenberg-Marquardt still converges to the minimum of the exact residuals).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import robot
from calib.compliance_settings import CompliantSettings
from calib.model import (
    ALL_NAMES,
    COMPLIANCE_NAMES,
    EXTRA_NAMES,
    INDEX,
    PAPER_30,
    SystemModel,
    cross,
)
from calib.transforms import apply

F64 = NDArray[np.float64]
GRAVITY_M_S2 = 9.81
MODEL_KINDS = ("rigid", "compliant")
#: The compliance coefficients identified by default (the payload terms are configured).
ARM_COMPLIANCE: tuple[str, ...] = ("c2_upper", "c2_fore", "c3_fore")
LENGTH_NAMES: tuple[str, ...] = tuple(n for n in ALL_NAMES if n[0] in "ad" and n[1:].isdigit())
COMPLIANT_NAMES: tuple[str, ...] = ALL_NAMES + EXTRA_NAMES


@dataclass(frozen=True)
class CompliantModel(SystemModel):
    """SystemModel with J2/J3 gravity deflection and thermal growth (module docstring).
    Full parameter vectors have 43 entries: the 37 rigid ones, then EXTRA_NAMES."""

    settings: CompliantSettings = field(default_factory=CompliantSettings)
    base_height_mm: float = robot.BASE_LINK_TO_WORLD_Z_MM
    name: str = "fanuc-m710ic50-mdh30-compliant"
    _last_levers: list[Any] = field(default_factory=list, init=False, repr=False, compare=False)
    kind: ClassVar[str] = "compliant"
    names: ClassVar[tuple[str, ...]] = COMPLIANT_NAMES

    @staticmethod
    def of(model: SystemModel, settings: CompliantSettings | None = None) -> CompliantModel:
        """The compliant model on the nominal geometry of a rigid one."""
        return CompliantModel(
            model.T_part_base_nominal,
            model.T_flange_sensor_nominal,
            model.limits,
            settings=settings or CompliantSettings(),
        )

    def nominal_x(self) -> F64:
        """Full vector (43,): rigid nominal; arm compliance 0; payload terms from the payload;
        the configured expansion coefficient."""
        s = self.settings
        w_n = GRAVITY_M_S2 * s.payload_kg * s.nominal_compliance_rad_per_nm
        extra = {"c2_payload": w_n, "c3_payload": w_n, "expansion_per_k": s.expansion_per_k}
        x = np.concatenate([super().nominal_x(), np.zeros(len(EXTRA_NAMES))])
        for name, value in extra.items():
            x[INDEX[name]] = value
        return x

    def carried(self, x: F64, temp_c: float | None = None) -> F64:
        """A full vector of this model from one of a rigid model (37 entries) that predicts
        the points the rigid one predicts, at `temp_c` [degC], the cell temperature the rigid
        version was calibrated at (default: reference_temp_c, a version that does not say);
        at another temperature T it adds the growth of T - temp_c only. A vector of this
        model is returned as it is.

        The rigid lengths are the arm's at temp_c: they are referred to reference_temp_c
        (divided by s(temp_c), the base moved down by its J2 height's growth), with the
        configured expansion coefficient; the points are linear in the lengths, so the
        carried vector at temp_c is the rigid one (to rounding) in `fk` and `points_part`
        alike. Every compliance term is 0, the payload's too: the rigid fit absorbed what
        its chain could of the gravity deflection at its configurations, and no deflection
        is the one choice that predicts the rigid points at every configuration (configured
        payload terms would count the payload twice). An identification that starts here
        identifies the arm terms; the payload terms, not identified, stay 0 (the wrist-flange
        lever is ~0.2 m: a 6 kg sensor's deflection moves a point 2 um at most)."""
        x = np.asarray(x, dtype=float)
        if x.shape == (len(self.names),):
            return x.copy()
        n_rigid = len(self.names) - len(EXTRA_NAMES)
        if x.shape != (n_rigid,):
            raise ValueError(f"expected {n_rigid} or {len(self.names)} parameters, got {x.shape}")
        out = np.concatenate([x, np.zeros(len(EXTRA_NAMES))])
        out[INDEX["expansion_per_k"]] = self.settings.expansion_per_k
        ds = 0.0 if temp_c is None else float(self.scale_of(out, temp_c))
        cols = [INDEX[n] for n in LENGTH_NAMES]
        out[cols] = x[cols] / (1.0 + ds)
        out[0:3] = x[0:3] - self.T_part_base(out)[:3, 2] * self.base_height_mm * ds
        return out

    def default_active(self, temp_c: F64 | None = None) -> tuple[str, ...]:
        """The paper's 30, the arm compliance and, when the temperatures span enough and the
        settings ask for it, the expansion coefficient."""
        names = (*PAPER_30, *ARM_COMPLIANCE)
        if (
            self.settings.identify_expansion
            and temp_span_k(temp_c) >= self.settings.min_temp_span_k
        ):
            names += ("expansion_per_k",)
        return names

    # -- gravity deflection ----------------------------------------------------------------
    def _axis_frames(self, x: F64, phi: F64) -> list[F64]:
        """Frames (N, 4, 4) just after each joint rotation Rz(phi_i), i = 1..6: origin on
        joint i's axis, z along it."""
        consts = self._constants(x)
        c, s = np.cos(phi), np.sin(phi)
        M = np.broadcast_to(consts[0], (phi.shape[0], 4, 4)).copy()
        out = []
        for i in range(6):
            col0 = M[:, :, 0].copy()
            M[:, :, 0] = col0 * c[:, i, None] + M[:, :, 1] * s[:, i, None]
            M[:, :, 1] = M[:, :, 1] * c[:, i, None] - col0 * s[:, i, None]
            out.append(M.copy())
            M = M @ consts[i + 1]
        return out

    def levers_m(self, x: F64, phi_rigid: F64) -> F64:
        """Gravity levers (N, 5) [m] in the order of COMPLIANCE_NAMES, at rigid angles (the
        last result is kept: one update asks for it three times)."""
        key = x.tobytes() + phi_rigid.tobytes()
        entry = self._last_levers[0] if self._last_levers else None
        if entry is not None and entry[0] == key:
            out: F64 = entry[1]
            return out
        L = self._levers_m(x, phi_rigid)
        self._last_levers[:] = [(key, L)]
        return L

    def _levers_m(self, x: F64, phi_rigid: F64) -> F64:
        A = self._axis_frames(x, phi_rigid)
        down = -self._pieces(x).T_pb[:3, 2]
        o2, z2 = A[1][:, :3, 3], A[1][:, :3, 2]
        o3, z3 = A[2][:, :3, 3], A[2][:, :3, 2]
        w = A[4][:, :3, 3]
        f = A[5][:, :3, 3] + A[5][:, :3, 2] * x[INDEX["d6"]]

        def lever(a: F64, b: F64, z: F64) -> F64:
            out: F64 = np.einsum("ni,ni->n", cross((b - a) / 1000.0, down), z)
            return out

        return np.stack(
            [
                lever(o2, o3, z2),
                lever(o3, w, z2),
                lever(o3, w, z3),
                lever(w, f, z2),
                lever(w, f, z3),
            ],
            axis=1,
        )

    def deflection_rad(self, x: F64, q_deg: ArrayLike) -> F64:
        """Joint deflections (N, 6) [rad] (only J2, J3 nonzero) added to the joint angles."""
        phi = super().joint_phi(x, np.atleast_2d(np.asarray(q_deg, dtype=float)))
        return self._deflection(x, phi)

    def _deflection(self, x: F64, phi_rigid: F64) -> F64:
        c = x[[INDEX[n] for n in COMPLIANCE_NAMES]]
        d = np.zeros_like(phi_rigid)
        if not np.any(c):
            return d  # exactly the rigid angles when the terms are off
        L = self.levers_m(x, phi_rigid)
        d[:, 1] = L[:, 0] * c[0] + L[:, 1] * c[1] + L[:, 3] * c[3]
        d[:, 2] = L[:, 2] * c[2] + L[:, 4] * c[4]
        return d

    def joint_phi(self, x: F64, q_deg: ArrayLike) -> F64:
        """Rotation angles of the six z-rotations (..., 6) [rad], deflected by gravity."""
        phi = super().joint_phi(x, q_deg)
        if phi.ndim == 1:
            return phi + self._deflection(x, phi[None])[0]
        return phi + self._deflection(x, phi)

    # -- thermal growth --------------------------------------------------------------------
    def scale_of(self, x: F64, temp_c: ArrayLike) -> F64:
        """s - 1 = expansion_per_k (T - reference_temp_c), shape of temp_c."""
        dT = np.asarray(temp_c, dtype=float) - self.settings.reference_temp_c
        out: F64 = x[INDEX["expansion_per_k"]] * dT
        return out

    def fk(
        self, x: F64, q_deg: ArrayLike, *, flange: bool = False, temp_c: float | None = None
    ) -> F64:
        """As SystemModel.fk, with every arm length grown exactly to one cell temperature."""
        if temp_c is None:
            return super().fk(x, q_deg, flange=flange)
        ds = float(self.scale_of(x, temp_c))
        x_t = x.copy()
        cols = [INDEX[n] for n in LENGTH_NAMES]
        x_t[cols] = x[cols] * (1.0 + ds)
        x_t[0:3] = x[0:3] + self._pieces(x).T_pb[:3, 2] * self.base_height_mm * ds
        return super().fk(x_t, q_deg, flange=flange)

    def points_part(
        self, x: F64, q_deg: ArrayLike, c_sensor_mm: ArrayLike, temp_c: ArrayLike | None = None
    ) -> F64:
        """Sphere centres in the part frame (N, 3) with deflection and, given the cell
        temperature of each measurement `temp_c` (N,) [degC], thermal growth (first order)."""
        if temp_c is None:
            return apply(self.fk(x, q_deg), np.asarray(c_sensor_mm, dtype=float))
        return self.point_and_jacobian(x, q_deg, c_sensor_mm, (), temp_c)[0]

    def point_and_jacobian(
        self,
        x: F64,
        q_deg: ArrayLike,
        c_sensor_mm: ArrayLike,
        active: Sequence[str],
        temp_c: ArrayLike | None = None,
    ) -> tuple[F64, F64]:
        """P_i (N, 3) as `points_part` and d P_i / d x_active (N, 3, L), the extra columns
        analytic (module docstring)."""
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))
        c_s = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (q.shape[0], 3))
        rigid = [n for n in active if n in ALL_NAMES]
        extra = ["dtheta2", "dtheta3"] + (list(LENGTH_NAMES) if temp_c is not None else [])
        need = [*rigid, *(n for n in dict.fromkeys(extra) if n not in rigid)]
        p, J_r = super().point_and_jacobian(x, q, c_s, need)
        col = {n: k for k, n in enumerate(need)}
        J = np.zeros((q.shape[0], 3, len(active)))
        G = np.zeros_like(p)
        if temp_c is not None:
            G = self._growth_mm(x, J_r[:, :, [col[n] for n in LENGTH_NAMES]])
            p = p + self.scale_of(x, temp_c).reshape(-1, 1) * G
        if not any(n in COMPLIANCE_NAMES for n in active):
            L = np.zeros((q.shape[0], len(COMPLIANCE_NAMES)))  # not needed
        else:
            L = self.levers_m(x, super().joint_phi(x, q))
        for k, name in enumerate(active):
            if name in col:
                J[:, :, k] = J_r[:, :, col[name]]
            elif name in COMPLIANCE_NAMES:
                i = COMPLIANCE_NAMES.index(name)
                joint = "dtheta2" if name.startswith("c2") else "dtheta3"
                J[:, :, k] = J_r[:, :, col[joint]] * L[:, i, None]
            elif temp_c is not None:  # expansion_per_k
                dT = np.asarray(temp_c, dtype=float) - self.settings.reference_temp_c
                J[:, :, k] = dT.reshape(-1, 1) * G
        return p, J

    def _growth_mm(self, x: F64, J_lengths: F64) -> F64:
        """G (N, 3) [mm] = dP/ds: sum_k L_k dP/dL_k (J_lengths (N, 3, K) in the order of
        LENGTH_NAMES) plus the J2 height's growth along the base z axis."""
        lengths = x[[INDEX[n] for n in LENGTH_NAMES]]
        out: F64 = J_lengths @ lengths + self._pieces(x).T_pb[:3, 2] * self.base_height_mm
        return out


def temp_span_k(temp_c: ArrayLike | None) -> float:
    """Range of the measurement temperatures [K] (0 without temperatures)."""
    if temp_c is None:
        return 0.0
    t = np.asarray(temp_c, dtype=float)
    return float(t.max() - t.min()) if t.size else 0.0


def carry(
    target: SystemModel, model: SystemModel, x: F64, temp_c: float | None = None
) -> tuple[SystemModel, F64]:
    """(model, x) of parameters of `model` as a service that identifies `target` uses them: a
    rigid model's carried into a compliant target (CompliantModel.carried: the same points at
    `temp_c`, the version's calibration temperature, None when unknown); otherwise as they
    are (a compliant version keeps its compliance under a rigid target: nothing is thrown
    away)."""
    if isinstance(target, CompliantModel) and not isinstance(model, CompliantModel):
        return target, target.carried(x, temp_c)
    return model, x


def select_model(
    kind: str, model: SystemModel, settings: CompliantSettings | None = None
) -> SystemModel:
    """The model of `kind` ("rigid" | "compliant") on the nominal geometry of `model`."""
    if kind == "rigid":
        return SystemModel(model.T_part_base_nominal, model.T_flange_sensor_nominal, model.limits)
    if kind == "compliant":
        return CompliantModel.of(model, settings)
    raise ValueError(f"unknown model '{kind}' (choose from {', '.join(MODEL_KINDS)})")
