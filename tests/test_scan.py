"""Scan conventions, the Z loop and the frame pipeline on analytic cases."""

import numpy as np
import pytest

from afmsim.samples import HeightMap
from afmsim.scan import (RasterGeometry, ZFeedback, ZStage, raster_trajectory, scan_frame, surface_under_tip,
                         track_surface)
from afmsim.compensation import NominalLinear
from afmsim.stage import default_stage

UM, NM = 1e-6, 1e-9
GEOMETRY = RasterGeometry(size=(8 * UM, 4 * UM), offset=(3 * UM, 5 * UM), pixels=16, lines=4,
                          line_rate_hz=2.0, samples_per_pixel=4, approach_s=0.2)


def test_trace_runs_left_to_right_and_retrace_right_to_left():
    traj = raster_trajectory(GEOMETRY)
    frame = traj.x[traj.frame_start:].reshape(4, 2, 16 * 4)
    assert np.all(np.diff(frame[:, 0]) > 0) and np.all(np.diff(frame[:, 1]) < 0)
    assert traj.x[0] == 0.0 and traj.y[0] == 0.0          # starts at rest (de-energised stage)
    assert np.all(np.diff(traj.t) == pytest.approx(1 / GEOMETRY.sample_rate_hz))


def test_images_are_stored_at_intended_pixel_centres_left_to_right():
    traj = raster_trajectory(GEOMETRY)
    trace, retrace = traj.to_images(traj.x)
    np.testing.assert_allclose(trace, np.broadcast_to(GEOMETRY.pixel_centres_x, trace.shape), atol=1e-15)
    np.testing.assert_allclose(retrace, np.broadcast_to(GEOMETRY.pixel_centres_x, retrace.shape), atol=1e-15)
    rows, _ = traj.to_images(traj.y)
    np.testing.assert_allclose(rows[:, 0], GEOMETRY.line_centres_y)    # lines ordered along +y


def test_surface_under_tip_is_bilinear():
    hm = HeightMap(np.add.outer(np.arange(5) * 2.0, np.arange(6) * 3.0) * NM, (1 * UM, 1 * UM), origin=(10 * UM, 20 * UM))
    x = np.array([10.5, 12.25]) * UM
    y = np.array([20.0, 23.5]) * UM
    expected = (3.0 * (x - 10 * UM) / UM + 2.0 * (y - 20 * UM) / UM) * NM
    np.testing.assert_allclose(surface_under_tip(hm, x, y), expected, rtol=1e-12)


def test_z_loop_tracks_a_flat_surface_and_a_step_up():
    fs = 2000.0
    surface = np.where(np.arange(4000) < 2000, 0.0, 500 * NM)
    height = track_surface(surface, fs, ZStage(hysteresis=False), ZFeedback(deflection_noise_m=0.0), np.random.default_rng(0))
    assert np.ptp(height[100:1990]) < 1e-12
    assert height[-1] - height[0] == pytest.approx(500 * NM, rel=1e-3)


def test_z_loop_parachutes_downhill_at_ki_times_setpoint():
    """Datasheet mechanism: off the surface the error saturates at −setpoint and Z falls at Ki·setpoint."""
    fs, ki, setpoint = 20000.0, 2000.0, 20 * NM
    surface = np.where(np.arange(4000) < 1000, 500 * NM, 0.0)
    feedback = ZFeedback(ki_per_s=ki, kp=0.0, setpoint_m=setpoint, deflection_noise_m=0.0)
    height = track_surface(surface, fs, ZStage(hysteresis=False), feedback, np.random.default_rng(0))
    falling = height[1005:1100]
    rate = -np.median(np.diff(falling)) * fs
    assert rate == pytest.approx(ki * setpoint, rel=0.05)
    assert height[-1] == pytest.approx(0.0, abs=1 * NM)


def test_z_loop_rejects_an_unstable_loop_rate():
    with pytest.raises(ValueError, match="ki_per_s"):
        track_surface(np.zeros(10), 1000.0, ZStage(), ZFeedback(ki_per_s=3000.0, loop_rate_hz=1000.0), np.random.default_rng(0))


def test_perfect_stage_gives_identical_trace_and_retrace_at_the_true_positions():
    """With no stage errors and a stiff Z loop, both images are the surface at the intended pixels."""
    geometry = RasterGeometry(size=(10 * UM, 10 * UM), offset=(5 * UM, 5 * UM), pixels=32, lines=8,
                              line_rate_hz=1.0, samples_per_pixel=4, approach_s=0.1)
    x = np.arange(-50, 250) * 0.1 * UM
    X, Y = np.meshgrid(x, x)
    z = 300 * NM * np.exp(-((X - 10 * UM) ** 2 + (Y - 10 * UM) ** 2) / (2 * (2 * UM) ** 2))
    surface = HeightMap(z, (0.1 * UM, 0.1 * UM), origin=(x[0], x[0]))
    stage = default_stage().ideal()
    control = NominalLinear(stage.x.params.sensitivity_m_per_V)
    images = scan_frame(surface, raster_trajectory(geometry), stage, control, control, ZStage(hysteresis=False),
                        ZFeedback(ki_per_s=20000.0, loop_rate_hz=200000.0, deflection_noise_m=0.0), np.random.default_rng(1))
    PX, PY = np.meshgrid(geometry.pixel_centres_x, geometry.line_centres_y)
    truth = surface_under_tip(surface, PX.ravel(), PY.ravel()).reshape(PX.shape)
    for image in (images.trace.z, images.retrace.z):
        level = image - image.mean() + truth.mean()
        assert np.max(np.abs(level - truth)) < 3 * NM
    np.testing.assert_allclose(images.actual_x_trace, np.broadcast_to(geometry.pixel_centres_x, (8, 32)), atol=1e-12)
