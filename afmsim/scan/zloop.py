"""Contact-mode Z feedback: a hysteretic Z stage under a PI loop on cantilever deflection.

Geometry. The Z stage carries the cantilever base; its extension ``z`` (m) lifts the base. The
free (undeflected) tip height is ``b = b0 + z``; the cantilever deflection is
``δ = max(s − b, 0)`` where ``s`` is the tip-dilated surface height under the tip's *actual* XY
position. ``δ = 0`` means the tip has left the surface (parachuting on a downhill edge).

Controller (per loop step, at ``loop_rate_hz``): error ``e = δ_measured − setpoint``; the command
``z_cmd = kp·e + ki·∫e dt`` (metres of nominal Z travel) becomes the drive voltage
``u = u_centre + z_cmd / S_nominal``, clipped to the amplifier range. The recorded height is what a
real AFM records: ``u·S_nominal`` (Z drive × nominal sensitivity), so the Z stage's own hysteresis
and the loop's lag both show in the image.

Z stage hysteresis: a Bouc–Wen element on the drive voltage (a different family from the XY
compensators), ``z = S·(u − h)``, ``ḣ = A·u̇ − β·|u̇|·h − γ·u̇·|h|`` (h in volts).

Not modelled: Z resonance and amplifier lag (the loop bandwidth, ≤ 1 kHz, sits well below a
1–5 kHz Z resonance — datasheet, L confidence), lateral friction and indentation of soft samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["ZStage", "ZFeedback", "track_surface"]


@dataclass(frozen=True)
class ZStage:
    """Z nanopositioning stage (paper §3.1: 12 µm travel, 0.6 µm/V).

    Attributes
    ----------
    sensitivity_m_per_V : float
        Nominal sensitivity S, m/V (0.6 µm/V, paper).
    max_voltage_V : float
        Amplifier range 0…max, V (12 µm / 0.6 µm/V = 20 V).
    hysteresis : bool
        Bouc–Wen hysteresis on (True) or a linear stage (False).
    bw_alpha, bw_beta_per_V, bw_gamma_per_V : float
        Bouc–Wen A (dimensionless), β and γ (1/V). Defaults give a loop width of about 10 % of
        the travel at full range (PI piezo tutorial figure, datasheet H row) and well under 1 %
        for the sub-micrometre excursions of imaging.
    """

    sensitivity_m_per_V: float = 0.6e-6
    max_voltage_V: float = 20.0
    hysteresis: bool = True
    bw_alpha: float = 0.22
    bw_beta_per_V: float = 0.045
    bw_gamma_per_V: float = 0.015


@dataclass(frozen=True)
class ZFeedback:
    """Contact-mode PI loop on deflection (datasheet: mostly integral, Ki 600–6000 s⁻¹).

    Attributes
    ----------
    ki_per_s : float
        Integral gain, s⁻¹ (≈ loop crossover in rad/s).
    kp : float
        Proportional gain, dimensionless.
    setpoint_m : float
        Deflection setpoint, m (5–50 nm).
    deflection_noise_m : float
        RMS deflection-detection noise, m (thermal: 0.08–0.64 nm).
    loop_rate_hz : float
        Rate of the digital loop, Hz (numerical knob; ki/loop_rate must stay below ~0.5).
    """

    ki_per_s: float = 3000.0
    kp: float = 0.1
    setpoint_m: float = 20e-9
    deflection_noise_m: float = 0.1e-9
    loop_rate_hz: float = 50_000.0


@njit(cache=True, nogil=True)
def _track(surface, substeps, dt, ki, kp, setpoint, noise, s_nom, s_true, u_max, hyst, a, beta, gamma, out):  # pragma: no cover
    n = surface.shape[0]
    u_centre = 0.5 * u_max
    h = 0.0
    u = u_centre
    # engaged at equilibrium on the first sample: b0 chosen so that delta = setpoint at u_centre
    b0 = surface[0] - setpoint - s_true * u_centre
    integral = 0.0
    for k in range(n):
        s_prev = surface[k - 1] if k > 0 else surface[0]
        s_next = surface[k + 1] if k + 1 < n else surface[k]
        acc = 0.0
        for j in range(substeps):
            # loop step j sits at sample position k − ½ + (j + ½)/substeps: the sample's own interval
            frac = (j + 0.5) / substeps - 0.5
            if frac < 0.0:
                s = surface[k] + frac * (surface[k] - s_prev)
            else:
                s = surface[k] + frac * (s_next - surface[k])
            b = b0 + s_true * (u - h)
            delta = s - b
            if delta < 0.0:
                delta = 0.0
            e = delta + noise[k] - setpoint
            integral += e * dt
            u_new = u_centre + (kp * e + ki * integral) / s_nom
            if u_new < 0.0:
                u_new = 0.0
            elif u_new > u_max:
                u_new = u_max
            if hyst:
                du = u_new - u
                h += a * du - beta * abs(du) * h - gamma * du * abs(h)
            u = u_new
            acc += u
        out[k] = acc / substeps * s_nom


def track_surface(surface_m: np.ndarray, sample_rate_hz: float, stage: ZStage, feedback: ZFeedback,
                  rng: np.random.Generator) -> np.ndarray:
    """Run the Z loop along a tip path; return the recorded height per sample, metres.

    ``surface_m[k]`` is the dilated surface height under the tip's actual XY position at sample
    ``k`` (sampled at ``sample_rate_hz``). Sample ``k`` stands for the time interval centred on it;
    the loop runs ``ceil(loop_rate_hz / sample_rate_hz)`` steps across that interval with the
    surface interpolated linearly between neighbouring samples, and the recorded height is the
    interval's mean Z drive × nominal sensitivity, offset so the first sample reads its surface
    height.
    """
    surface = np.ascontiguousarray(surface_m, dtype=np.float64)
    substeps = max(1, int(np.ceil(feedback.loop_rate_hz / sample_rate_hz)))
    dt = 1.0 / (sample_rate_hz * substeps)
    if feedback.ki_per_s * dt > 0.5:
        raise ValueError(f"z_feedback.ki_per_s × loop period = {feedback.ki_per_s * dt:.3g} must be <= 0.5; "
                         f"raise numerics loop rate or lower ki")
    noise = rng.normal(0.0, feedback.deflection_noise_m, surface.size)
    out = np.empty_like(surface)
    # The stage is calibrated (as users do on a step standard) so that its small-signal slope
    # S_true·(1 − A) equals the nominal sensitivity that converts the drive into height.
    true_sensitivity = stage.sensitivity_m_per_V / (1.0 - stage.bw_alpha) if stage.hysteresis else stage.sensitivity_m_per_V
    _track(surface, substeps, dt, feedback.ki_per_s, feedback.kp, feedback.setpoint_m, noise,
           stage.sensitivity_m_per_V, true_sensitivity, stage.max_voltage_V, stage.hysteresis,
           stage.bw_alpha, stage.bw_beta_per_V, stage.bw_gamma_per_V, out)
    return out - out[0] + surface[0]
