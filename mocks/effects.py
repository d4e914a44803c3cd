"""Hidden non-geometric effects of the twin, each a physical model with a seed and a magnitude.

The magnitude (mm) is what a geometric calibration cannot absorb: the effect's displacement of the
reflectors over a reference campaign (the cell's points and stations, 40 random feasible poses in
campaign order, 20 s per measurement) minus its least-squares projection on the geometric model
(irreducible parameters, station transforms, point positions), as an RMS per coordinate. So "2x the
noise" means a residual structure of twice the tracker noise, whatever the effect.

Joint effects act on the angle the joint really has: q_true = q_read + dq(q_read, approach, ...). The
controller reports q_read (its encoders), which is what the measurement table holds.

Thermal growth is a uniform linear expansion of the whole robot: every length (base column, links, tool
offsets) grows by the factor 1 + rate t. A rigid chain whose translations all scale by one factor scales every
point of it about the chain's first frame, so the reflector moves to pivot + (1 + rate t) (p - pivot), the pivot
(THERMAL_PIVOTS) a parameter of the effect: `base`, the robot bolted to its mount grows as a whole away from the
base frame's origin; `first_joint`, the base column keeps its length (a massive casting that lags behind the
warming motors, or a temperature-controlled pedestal) and the arm grows about the first joint's frame.

A first-order warm-up (thermal_warmup) grows every length by g(t) = e_inf (1 - exp(-t / tau)) about its pivot, the
same pivots; a payload (payload_compliance) of a stated mass is bolted to the flange at a time of the campaign, its
centre of mass at the last link's (the robot config's), and every joint deflects by its compliance times the gravity
torque it then holds (the config's mass model with the payload: the cell states both); the table records the load
of each row (column `load_kg`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from trackcal.calib.diagnose.extensions import CAUSES, payload_torques
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.pinmodel import gravity_torques
from trackcal.calib.model.rigid import exp_so3

THERMAL_PIVOTS = ("base", "first_joint")
# Linear expansion coefficients near 20 degC (CRC Handbook of Chemistry and Physics, "Thermal Expansion of
# Solids"): iron 11.8e-6 /K (structural steels 11-13e-6), aluminium 23.1e-6 /K. A steel robot warming
# 1 K per hour after power-on grows 11.8 ppm/h: the shape of the twin's growth before it is scaled.
STEEL_PER_K = 11.8e-6
WARMUP_K_PER_S = 1.0 / 3600.0
WARMUP_K = 10.0  # a first-order warm-up's steady rise of the links (K): the unit shape of thermal_warmup
PAYLOAD_KG = 150.0  # the payload bolted on during the campaign (a KR 270's rated payload is 270 kg)


@dataclass
class Effects:
    """The true hidden effects (internal units: rad, N m, s, mm)."""

    compliance: np.ndarray | None = None  # (n,) rad per N m
    mass_chain: Chain | None = None  # the true mass model (the config's is only rough)
    backlash: np.ndarray | None = None  # (n,) rad, full width
    encoder_scale: np.ndarray | None = None  # (n,)
    cyclic: list[tuple[int, int, float, float]] = field(default_factory=list)  # (joint, harmonic, rad, phase)
    thermal_per_s: float = 0.0  # growth rate of every length
    thermal_pivot: np.ndarray = field(default_factory=lambda: np.zeros(3))  # mm, robot base frame
    shift: tuple[str, float, np.ndarray, np.ndarray] | None = None  # (station, after t_s, rotation, translation)
    warmup_inf: float = 0.0  # saturated growth of every length (first-order warm-up)
    warmup_tau_s: float = 1.0
    warmup_pivot: np.ndarray = field(default_factory=lambda: np.zeros(3))
    payload_compliance: np.ndarray | None = None  # (n,) rad per N m
    payload_chain: Chain | None = None  # the mass model the payload's torques are computed with (the config's)
    payload: tuple[float, float] | None = None  # (kg, mounted after t_s)
    coupling: np.ndarray | None = None  # (n, n): dq = coupling @ q, the wrist's coupling-ratio errors
    range_scale: dict[str, float] = field(default_factory=dict)  # station -> k: it measures (1 + k) x
    nest_sag: dict[str, float] = field(default_factory=dict)  # point -> mm along gravity (base -z)

    def load_at(self, t_s: np.ndarray) -> np.ndarray:
        """(N,) the payload (kg) mounted at times t_s."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        return np.zeros(len(t)) if self.payload is None else np.where(t > self.payload[1], self.payload[0], 0.0)

    def joint_errors(self, q: np.ndarray, approach: np.ndarray, t_s: float = 0.0) -> np.ndarray:
        """(N, n) rad: true minus reported joint angles for reported q (N, n) and approach signs (N, n) at time t_s."""
        dq = np.zeros_like(q)
        if self.payload_compliance is not None:
            chain = self.payload_chain
            loads = np.full(len(q), float(self.load_at(t_s)[0]))
            dq += self.payload_compliance * payload_torques(chain, q, loads, np.asarray(chain.joints[-1].com, float))
        if self.compliance is not None:
            dq += self.compliance * gravity_torques(self.mass_chain, q)
        if self.backlash is not None:
            dq += 0.5 * self.backlash * approach
        if self.encoder_scale is not None:
            dq += self.encoder_scale * q
        for j, h, amp, phase in self.cyclic:
            dq[:, j] += amp * np.sin(h * q[:, j] + phase)
        if self.coupling is not None:
            dq += q @ self.coupling.T
        return dq

    def sag(self, point: str) -> np.ndarray:
        """(3,) mm: the displacement of the reflector in its nest, along gravity (base -z), in the base frame."""
        return np.array([0.0, 0.0, -self.nest_sag.get(point, 0.0)])

    def grown(self, p: np.ndarray, t_s: float) -> np.ndarray:
        """Points p (..., 3) of the rigid robot (base frame, mm) after t_s of uniform thermal growth."""
        p = self.thermal_pivot + (1.0 + self.thermal_per_s * t_s) * (p - self.thermal_pivot)
        if self.warmup_inf:
            g = -self.warmup_inf * np.expm1(-t_s / self.warmup_tau_s)
            p = self.warmup_pivot + (1.0 + g) * (p - self.warmup_pivot)
        return p

    def scaled(self, factor: float) -> Effects:
        def mul(v):
            return None if v is None else v * factor

        shift = None
        if self.shift is not None:
            sid, t, rvec, tvec = self.shift
            shift = (sid, t, rvec * factor, tvec * factor)
        return replace(
            self,
            compliance=mul(self.compliance),
            backlash=mul(self.backlash),
            encoder_scale=mul(self.encoder_scale),
            cyclic=[(j, h, a * factor, p) for j, h, a, p in self.cyclic],
            thermal_per_s=self.thermal_per_s * factor,
            shift=shift,
            warmup_inf=self.warmup_inf * factor,
            payload_compliance=mul(self.payload_compliance),
            coupling=mul(self.coupling),
            range_scale={k: v * factor for k, v in self.range_scale.items()},
            nest_sag={k: v * factor for k, v in self.nest_sag.items()},
        )

    def to_doc(self) -> dict:
        """The hidden effects' true parameters in boundary units (deg, mm, s), for the twin's truth file; {} when
        there are none."""
        doc: dict = {}
        if self.compliance is not None:
            doc["joint_compliance"] = {"deg_per_n_m": np.degrees(self.compliance).tolist()}
            if self.mass_chain is not None:
                doc["joint_compliance"]["masses"] = [
                    {"joint": j.name, "mass_kg": float(j.mass_kg), "com_mm": np.asarray(j.com, dtype=float).tolist()}
                    for j in self.mass_chain.joints
                ]
        if self.backlash is not None:
            doc["backlash"] = {"full_width_deg": np.degrees(self.backlash).tolist()}
        if self.encoder_scale is not None:
            doc["encoder_scale"] = {"scale": np.asarray(self.encoder_scale, dtype=float).tolist()}
        if self.cyclic:
            doc["cyclic_error"] = [
                {"joint": int(j) + 1, "harmonic": int(h), "amplitude_deg": float(np.degrees(a)), "phase_rad": float(ph)}
                for j, h, a, ph in self.cyclic
            ]
        if self.thermal_per_s:
            doc["thermal_drift"] = {
                "growth_per_s": float(self.thermal_per_s),
                "pivot_mm": np.asarray(self.thermal_pivot, dtype=float).tolist(),
            }
        if self.warmup_inf:
            doc["thermal_warmup"] = {
                "e_inf": float(self.warmup_inf),
                "tau_s": float(self.warmup_tau_s),
                "pivot_mm": np.asarray(self.warmup_pivot, dtype=float).tolist(),
            }
        if self.payload_compliance is not None and self.payload is not None:
            doc["payload_compliance"] = {
                "deg_per_n_m": np.degrees(self.payload_compliance).tolist(),
                "load_kg": float(self.payload[0]),
                "mounted_after_t_s": float(self.payload[1]),
                "com_mm": np.asarray(self.payload_chain.joints[-1].com, float).tolist(),
            }
        if self.shift is not None:
            sid, t, rvec, tvec = self.shift
            doc["station_shift"] = {
                "station": sid,
                "after_t_s": float(t),
                "rotation_vector_deg": np.degrees(rvec).tolist(),
                "translation_mm": np.asarray(tvec).tolist(),
            }
        if self.coupling is not None:
            n = len(self.coupling)
            doc["wrist_coupling"] = {
                f"c{i + 1}{j + 1}": float(self.coupling[i, j])
                for i in range(n)
                for j in range(n)
                if self.coupling[i, j]
            }
        if self.range_scale:
            doc["range_scale"] = {"scale": dict(sorted(self.range_scale.items()))}
        if self.nest_sag:
            doc["nest_sag"] = {"sag_mm": dict(sorted(self.nest_sag.items()))}
        return doc

    def station_shift(self, station: str, t_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(rotation, translation) applied to the station's measurements after the change point."""
        if self.shift is None or station != self.shift[0] or t_s <= self.shift[1]:
            return None
        return exp_so3(self.shift[2]), self.shift[3]


def unit_effect(
    name: str,
    chain: Chain,
    rng: np.random.Generator,
    stations: list[str],
    t_mid: float,
    thermal_pivot: str = "base",
    points: tuple[str, ...] = (),
) -> Effects:
    """The shape of each effect at an arbitrary scale (then scaled to the requested magnitude); `thermal_pivot`
    (THERMAL_PIVOTS) is the point thermal growth keeps fixed; `points` the reference points (nest_sag)."""
    n = chain.dof
    if name == "joint_compliance":
        # the true masses differ from the config's rough model by ~15 %; wrist joints are softer
        joints = tuple(
            replace(j, mass_kg=j.mass_kg * (1 + 0.15 * rng.standard_normal()), com=j.com + rng.normal(0, 20.0, 3))
            for j in chain.joints
        )
        shape = np.array([1.0, 1.0, 1.0] + [2.0] * (n - 3))[:n]
        return Effects(compliance=1e-7 * shape, mass_chain=replace(chain, joints=joints))
    if name == "backlash":
        return Effects(backlash=np.radians(0.001) * np.array([1.0] * 3 + [1.5] * (n - 3))[:n])
    if name == "encoder_scale":
        return Effects(encoder_scale=1e-5 * rng.choice([-1.0, 1.0], n) * rng.uniform(0.5, 1.0, n))
    if name == "cyclic_error":
        return Effects(cyclic=[(j, 2, np.radians(0.001), rng.uniform(0, 2 * np.pi)) for j in range(1, min(n, 3))])
    if name == "thermal_drift":
        if thermal_pivot not in THERMAL_PIVOTS:
            raise ValueError(f"unknown thermal pivot {thermal_pivot!r}; choose from {', '.join(THERMAL_PIVOTS)}")
        pivot = np.zeros(3) if thermal_pivot == "base" else np.array(chain.base[:3, 3], dtype=float)
        return Effects(thermal_per_s=STEEL_PER_K * WARMUP_K_PER_S, thermal_pivot=pivot)
    if name == "thermal_warmup":  # tau of 10 to 30 min (t_mid: about a quarter of the 80 min reference campaign)
        if thermal_pivot not in THERMAL_PIVOTS:
            raise ValueError(f"unknown thermal pivot {thermal_pivot!r}; choose from {', '.join(THERMAL_PIVOTS)}")
        pivot = np.zeros(3) if thermal_pivot == "base" else np.array(chain.base[:3, 3], dtype=float)
        return Effects(
            warmup_inf=STEEL_PER_K * WARMUP_K, warmup_tau_s=t_mid * rng.uniform(0.5, 1.5), warmup_pivot=pivot
        )
    if name == "payload_compliance":  # bolted on halfway through the first station's block
        shape = np.array([1.0, 1.0, 1.0] + [2.0] * (n - 3))[:n]
        return Effects(payload_compliance=1e-7 * shape, payload_chain=chain, payload=(PAYLOAD_KG, t_mid))
    if name == "station_shift":
        return Effects(shift=(stations[0], t_mid, rng.normal(0, 1e-5, 3), rng.normal(0, 0.1, 3)))
    if name == "wrist_coupling":  # the wrist's coupling ratios off: A5 by A4, A6 by A4 and by A5
        c = np.zeros((n, n))
        for driven, driving in ((n - 2, n - 3), (n - 1, n - 3), (n - 1, n - 2)):
            c[driven, driving] = 1e-5 * rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.0)
        return Effects(coupling=c)
    if name == "range_scale":  # the last station's air data wrong; the first station is the model's reference
        return Effects(range_scale={stations[-1]: 1e-5 * rng.choice([-1.0, 1.0])})
    if name == "nest_sag":  # every nest sags by its own amount (their common part is a translation of the cell)
        return Effects(nest_sag={p: 0.01 * rng.uniform(0.2, 1.0) for p in points})
    raise ValueError(f"unknown effect {name!r}; choose from {', '.join(CAUSES)}")
