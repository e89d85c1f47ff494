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


@njit(cache=True, nogil=True, fastmath={"contract"})
def _track(surface, substeps, dt, ki, kp, setpoint, noise, s_nom, s_true, u_max, a, beta, gamma, out, err):  # pragma: no cover
    """The loop of the module docstring, rearranged so that one loop step is a short chain of operations.

    The loop is a serial recurrence (10⁷–10⁸ steps per frame), so its speed is the latency of one
    step. Same equations, other state variables: ``p = u_centre + ki·∫e dt / S_nom`` (V, the
    integral part of the drive), the gap ``g = s − b`` (m, surface minus free tip height) and the
    drive step ``du`` (V). Per step, with ``m = max(g, 0)`` and ``e = m + noise − setpoint``:
    ``du = clip(p + (kp/S_nom + ki·dt/S_nom)·e, 0, u_max) − u`` and ``p += ki·dt/S_nom·e``. The
    Bouc–Wen step ``Δh = A·du − β|du|h − γ·du|h|`` is ``du·(A − γ|h| ∓ βh)`` (− while extending,
    + while retracting), so the free height moves by ``S_true·(du − Δh) = du·S_true·(1 − A + γ|h|
    ± βh)`` and the next gap is ``g + Δs − that`` (Δs: the surface change to the next loop step);
    both branch factors are formed from ``h`` one step ahead, off the critical path. The gap is
    re-derived from ``(u, h)`` at every sample, so rounding cannot accumulate; ``A = β = γ = 0`` is
    the linear stage. Results agree with the direct form to rounding (≈1e-13 of the height range).
    ``err[k]``: the sample's mean measured error ``e`` (m), summed off the critical path.
    """
    n = surface.shape[0]
    u_centre = 0.5 * u_max
    h = 0.0
    u = u_centre
    p = u_centre
    # engaged at equilibrium on the first sample: b0 chosen so that delta = setpoint at u_centre
    b0 = surface[0] - setpoint - s_true * u_centre
    c_int = ki * dt / s_nom
    c_all = kp / s_nom + c_int
    k_lin = s_true * (1.0 - a)
    k_gamma = s_true * gamma
    k_beta = s_true * beta
    # loop step j sits at sample position k − ½ + (j + ½)/substeps: the sample's own interval, with
    # the surface linear towards the previous sample before the centre and the next one after it;
    # frac_* give each step's position on those two segments, step_* the change to the next step
    frac = (np.arange(substeps) + 0.5) / substeps - 0.5
    frac_prev = np.minimum(frac, 0.0)
    frac_next = np.maximum(frac, 0.0)
    step_prev = np.diff(np.append(frac_prev, frac_prev[-1]))
    step_next = np.diff(np.append(frac_next, frac_next[-1]))
    # Bouc–Wen: dh/du on the extending (du > 0) and retracting branch, and the free-height slope
    # db/du = S_true·(1 − dh/du), both from the current h; kept ready for the next step
    gain_up, gain_down = a, a
    slope_up, slope_down = k_lin, k_lin
    for k in range(n):
        sk = surface[k]
        down = sk - surface[k - 1] if k > 0 else 0.0
        up = surface[k + 1] - sk if k + 1 < n else 0.0
        noise_k = noise[k] - setpoint
        drive_noise = c_all * noise_k
        gap = sk + frac_prev[0] * down + frac_next[0] * up - (b0 + s_true * (u - h))
        acc = 0.0
        acc_m = 0.0
        for j in range(substeps):
            m = gap if gap > 0.0 else 0.0
            acc_m += m
            du = c_all * m + (p + drive_noise - u)
            du = min(max(du, -u), u_max - u)
            p += c_int * (m + noise_k)
            rising = du > 0.0
            gap = (gap + (step_prev[j] * down + step_next[j] * up)) - du * (slope_up if rising else slope_down)
            h += du * (gain_up if rising else gain_down)
            abs_h = abs(h)
            gain_up = (a - gamma * abs_h) - beta * h
            gain_down = (a - gamma * abs_h) + beta * h
            slope_up = (k_lin + k_gamma * abs_h) + k_beta * h
            slope_down = (k_lin + k_gamma * abs_h) - k_beta * h
            u += du
            acc += u
        out[k] = acc / substeps * s_nom
        err[k] = acc_m / substeps + noise_k


def track_surface(surface_m: np.ndarray, sample_rate_hz: float, stage: ZStage, feedback: ZFeedback,
                  rng: np.random.Generator, *, at_limit: np.ndarray | None = None,
                  error: np.ndarray | None = None) -> np.ndarray:
    """Run the Z loop along a tip path; return the recorded height per sample, metres.

    ``surface_m[k]`` is the dilated surface height under the tip's actual XY position at sample
    ``k`` (sampled at ``sample_rate_hz``). Sample ``k`` stands for the time interval centred on it;
    the loop runs ``ceil(loop_rate_hz / sample_rate_hz)`` steps across that interval with the
    surface interpolated linearly between neighbouring samples, and the recorded height is the
    interval's mean Z drive × nominal sensitivity, offset so the first sample reads its surface
    height.

    ``at_limit``, if given (a bool array of the surface's length), is set True at the samples over
    which the Z drive sat at an amplifier limit (0 V or ``max_voltage_V``) for the whole interval:
    there the tip no longer follows the surface (Z travel exceeded).

    ``error``, if given (a float array of the surface's length), receives the loop's error signal
    per sample: the measured deflection less the setpoint (m), the interval's mean — what an AFM
    records as its deflection (error) image: 0 while the tip follows the surface, −setpoint where it
    has left it.
    """
    surface = np.ascontiguousarray(surface_m, dtype=np.float64)
    substeps = max(1, int(np.ceil(feedback.loop_rate_hz / sample_rate_hz)))
    dt = 1.0 / (sample_rate_hz * substeps)
    if feedback.ki_per_s * dt > 0.5:
        raise ValueError(f"z_feedback.ki_per_s × loop period = {feedback.ki_per_s * dt:.3g} must be <= 0.5; "
                         f"raise numerics loop rate or lower ki")
    noise = rng.normal(0.0, feedback.deflection_noise_m, surface.size)
    out = np.empty_like(surface)
    if error is not None and (error.shape != surface.shape or error.dtype != np.float64 or not error.flags.c_contiguous):
        raise ValueError(f"error must be a contiguous float64 array of shape {surface.shape}, "
                         f"got {error.dtype} {error.shape}")
    err = error if error is not None else np.empty_like(surface)
    # The stage is calibrated (as users do on a step standard) so that its small-signal slope
    # S_true·(1 − A) equals the nominal sensitivity that converts the drive into height.
    true_sensitivity = stage.sensitivity_m_per_V / (1.0 - stage.bw_alpha) if stage.hysteresis else stage.sensitivity_m_per_V
    a, beta, gamma = (stage.bw_alpha, stage.bw_beta_per_V, stage.bw_gamma_per_V) if stage.hysteresis else (0.0, 0.0, 0.0)
    _track(surface, substeps, dt, feedback.ki_per_s, feedback.kp, feedback.setpoint_m, noise,
           stage.sensitivity_m_per_V, true_sensitivity, stage.max_voltage_V, a, beta, gamma, out, err)
    if at_limit is not None:  # out is the mean drive × S_nom, in [0, u_max·S_nom]; u ≥ 0 always
        top = stage.max_voltage_V * stage.sensitivity_m_per_V
        np.logical_or(out <= 0.0, out >= top * (1 - 1e-9), out=at_limit)
    start = out[0]
    out -= start
    out += surface[0]
    return out
