"""The global pose model (H_i = K [r1 r2 t_i]) against exact ground truth, with and without the focal length."""

from __future__ import annotations

import json

import numpy as np
import pytest

from inspect_pipe.mosaic import AlignParams, FolderSource, MosaicParams, RegisterParams, register, run_mosaic
from inspect_pipe.mosaic._align import Camera, homographies_from_poses, poses_from_homographies, thin, Correspondences
from inspect_pipe.mosaic._rectify import estimate_focal, focals_from_homography
from inspect_pipe.mosaic.metrics import corner_error


def test_focals_from_homography_recovers_a_rotating_cameras_focal_length():
    # GIVEN the homography of a camera (f = 700 px) rotating about its centre, in centred pixels
    f = 700.0
    K = np.diag([f, f, 1.0])
    a, b = np.deg2rad(4.0), np.deg2rad(-3.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]) @ np.array(
        [[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    H = K @ R @ np.linalg.inv(K)
    # THEN OpenCV's formula, restated, gives it back
    f0, f1 = focals_from_homography(H)
    assert f0 == pytest.approx(f, rel=1e-6) and f1 == pytest.approx(f, rel=1e-6)
    C = np.array([[1, 0, 320], [0, 1, 240], [0, 0, 1.0]])
    assert estimate_focal([C @ H @ np.linalg.inv(C)], (640, 480)) == pytest.approx(f, rel=1e-6)


def test_poses_round_trip_through_homographies():
    rng = np.random.default_rng(3)
    K = Camera(300.0, 128.0, 96.0).K
    H = {}
    for k in range(5):
        t = np.deg2rad(rng.normal(0, 3, 3))
        Rx = np.array([[1, 0, 0], [0, np.cos(t[0]), -np.sin(t[0])], [0, np.sin(t[0]), np.cos(t[0])]])
        Ry = np.array([[np.cos(t[1]), 0, np.sin(t[1])], [0, 1, 0], [-np.sin(t[1]), 0, np.cos(t[1])]])
        R = Rx @ Ry
        A = np.c_[R[:, :2], [rng.normal(0, 50), rng.normal(0, 50), 300 + rng.normal(0, 10)]]
        H[k] = np.linalg.inv(K @ A)
    R, t = poses_from_homographies(H, K)
    back = homographies_from_poses(np.concatenate([R[:, :, :2], t[:, :, None]], axis=2), K)
    for k, h in H.items():
        assert np.allclose(back[k], h / h[2, 2], atol=1e-9)


def test_thin_keeps_at_most_k_per_pair_spread_over_the_list():
    fi = np.r_[np.zeros(40, int), np.ones(5, int)]
    fj = fi + 1
    p = np.arange(90, dtype=float).reshape(45, 2)
    c = thin(Correspondences(fi, fj, p, p), 12)
    assert (c.fi == 0).sum() == 12 and (c.fi == 1).sum() == 5
    assert c.p[c.fi == 0][0, 0] == 0 and c.p[c.fi == 0][-1, 0] == 78  # first and last of pair (0, 1)


def test_the_sparse_jacobian_matches_dense_differences_with_the_gauge_frame_left_out():
    # GIVEN a pose problem of 3 frames, 2 pairs of 5 correspondences, focal length and k1 free, frame 1 the gauge
    from inspect_pipe.mosaic._align import _Problem

    rng = np.random.default_rng(3)
    fi, fj = np.r_[np.zeros(5, int), np.ones(5, int)], np.r_[np.ones(5, int), np.full(5, 2)]
    p, q = rng.uniform(0, 500, (10, 2)), rng.uniform(0, 500, (10, 2))
    corr = Correspondences(fi, fj, p, q)
    cam = Camera(600.0, 256.0, 192.0, 0.01, 0.0)
    R0 = np.stack([np.eye(3)] * 3)
    P = np.c_[rng.normal(0, 0.02, (3, 3)), rng.normal(0, 0.3, (3, 2)), 1 + rng.normal(0, 0.05, 3)]
    free = np.ones(3 * 6 + 2, bool)
    free[[8, 9, 10, 11]] = False
    prob = _Problem("pose", [0, 1, 2], fi, fj, corr, R0, cam, ("f", "k1"), free)
    full0 = np.r_[P.ravel(), cam.f, cam.k1]
    J = prob.jacobian(P, cam, prob.residuals(P, cam)).toarray()

    # THEN every column equals the residuals' central difference in that free unknown
    def r(x):
        Px, camx = prob.unpack(x, full0)
        return prob.residuals(Px, camx).ravel()

    x0 = full0[free]
    dense = np.empty((40, free.sum()))
    for c in range(free.sum()):
        h = 1e-6 * max(1.0, abs(x0[c]))
        e = np.zeros_like(x0)
        e[c] = h
        dense[:, c] = (r(x0 + e) - r(x0 - e)) / (2 * h)
    assert J.shape == dense.shape == (40, 16)
    assert np.allclose(J, dense, rtol=1e-3, atol=1e-3 * np.abs(dense).max())


def test_the_odometry_rows_of_the_jacobian_match_dense_differences():
    # GIVEN the same kind of problem with the odometry's rows: frames (0, 1) and (1, 2), frame 1 the gauge
    from inspect_pipe.mosaic._align import _PosePrior, _Problem

    rng = np.random.default_rng(5)
    fi, fj = np.r_[np.zeros(5, int), np.ones(5, int)], np.r_[np.ones(5, int), np.full(5, 2)]
    corr = Correspondences(fi, fj, rng.uniform(0, 500, (10, 2)), rng.uniform(0, 500, (10, 2)))
    cam = Camera(600.0, 256.0, 192.0)
    R0 = np.stack([np.eye(3)] * 3)
    P = np.c_[rng.normal(0, 0.02, (3, 3)), rng.normal(0, 0.3, (3, 2)), 1 + rng.normal(0, 0.05, 3)]
    free = np.ones(3 * 6 + 1, bool)
    free[[8, 9, 10, 11]] = False
    prior = _PosePrior(np.array([0, 1]), np.array([1, 2]), rng.normal(0, 0.3, (2, 2)), np.array([2.0, 0.5]), 1.0, 0.0)
    prob = _Problem("pose", [0, 1, 2], fi, fj, corr, R0, cam, ("f",), free, prior=prior)
    full0 = np.r_[P.ravel(), cam.f]
    r0 = prob.residuals(P, cam)
    J = prob.jacobian(P, cam, r0).toarray()

    def r(x):
        Px, camx = prob.unpack(x, full0)
        return prob.residuals(Px, camx)

    # THEN the correspondences' 40 rows are followed by the odometry's 4, and every column is the central difference
    x0 = full0[free]
    dense = np.empty((44, free.sum()))
    for c in range(free.sum()):
        e = np.zeros_like(x0)
        e[c] = h = 1e-6 * max(1.0, abs(x0[c]))
        dense[:, c] = (r(x0 + e) - r(x0 - e)) / (2 * h)
    assert J.shape == dense.shape == (44, 15) and len(r0) == 44
    assert np.abs(dense[40:]).max() > 0.1  # the odometry's rows do depend on the poses
    assert np.allclose(J, dense, rtol=1e-3, atol=1e-3 * np.abs(dense).max())
    assert np.allclose(J[40:, -1], 0.0)  # and not on the focal length


def _chain_with_a_weak_link(n_frames: int = 33, link: int = 12, keep: int = 12):
    """The first pass of the texture-poor validation sweep (fixture README) as a chain: only pairs of frames at most
    2 apart, and across frames ``link`` / ``link + 1`` a single pair of ``keep`` correspondences near its centre."""
    frames, H0, corr, pair_H, size, truth = _global_step_input("pass_end_vt173.npz")
    chain = np.isin(corr.fi, range(n_frames)) & np.isin(corr.fj, range(n_frames)) & (np.abs(corr.fi - corr.fj) <= 2)
    crossing = chain & (corr.fi <= link) & (corr.fj > link)
    chain &= ~crossing
    weak = np.flatnonzero(crossing & (corr.fi == link) & (corr.fj == link + 1))
    d = np.linalg.norm(corr.p[weak] - corr.p[weak].mean(0), axis=1)
    chain[weak[np.argsort(d)[:keep]]] = True
    sub = range(n_frames)
    return ({f: H0[f] for f in sub}, Correspondences(corr.fi[chain], corr.fj[chain], corr.p[chain], corr.q[chain]),
            {k: v for k, v in pair_H.items() if k[0] < n_frames and k[1] < n_frames}, size, {f: truth[f] for f in sub})


def _simulated_odometry(truth, size, seed: int, focal_px: float = 618.0, mirror: bool = False):
    """Odometry as the simulator's position estimate errs (demo flight, docs/mosaic.md): the true camera feet, a random
    walk of 2 px (about 3 mm) a frame and a constant velocity bias of 0.6 px (1 cm/s at 10 Hz) a frame."""
    from inspect_pipe.mosaic._align import Odometry, wall_feet

    rng = np.random.default_rng(seed)
    feet = wall_feet(truth, Camera(focal_px, size[0] / 2, size[1] / 2).K)
    a = rng.uniform(0, 2 * np.pi)
    steps = np.diff(feet, axis=0) + 0.6 * np.array([np.cos(a), np.sin(a)]) + rng.normal(0, 2.0, (len(feet) - 1, 2))
    odo = feet[0] + np.r_[[[0.0, 0.0]], np.cumsum(steps, axis=0)]
    if mirror:
        odo[:, 1] *= -1
    return Odometry(dict(zip(sorted(truth), odo)), noise_px=2.5, drift=0.05)


def test_odometry_holds_a_chain_across_a_weak_link():
    # GIVEN a 33-frame chain whose frames 12 and 13 are linked by 12 correspondences near one point only
    from inspect_pipe.mosaic._align import align_group

    H0, corr, pair_H, size, truth = _chain_with_a_weak_link()
    alone = align_group(H0, corr, size, focal_px=618.0, pair_H=pair_H)
    e_alone = corner_error(alone.H, truth, size)
    # WHEN the vehicle's odometry (the simulator's noise and drift, three draws) ties consecutive frames
    for seed in (1, 2, 3):
        res = align_group(H0, corr, size, focal_px=618.0, pair_H=pair_H, odometry=_simulated_odometry(truth, size, seed))
        e = corner_error(res.H, truth, size)
        # THEN the chain bends less at its far end (3.68 px alone; 2.52 / 3.22 / 3.08 px with the three draws)
        assert res.model == "pose" and res.odometry["used"] and res.odometry["displacements"] == 32
        assert e.max_px < 0.9 * e_alone.max_px and e.median_px < e_alone.median_px, (seed, e, e_alone)
        # AND the odometry and the fit agree about as its noise says
        assert 0.3 < res.odometry["rms_sigma"] < 1.0, res.odometry


def test_odometry_that_contradicts_the_images_is_not_used_and_says_why():
    # GIVEN the whole texture-poor sweep (5 passes) and odometry whose vertical axis is flipped (a flight log read with
    # the wrong convention: the passes climb where the images descend)
    from inspect_pipe.mosaic._align import align_group

    frames, H0, corr, pair_H, size, truth = _global_step_input("pass_end_vt173.npz")
    flipped = _simulated_odometry(truth, size, 1, mirror=True)
    res = align_group(H0, corr, size, focal_px=618.0, pair_H=pair_H, odometry=flipped)
    # THEN the prior is left out, with the share of the motion it could not explain, and the fit is the images' alone
    assert res.odometry["used"] is False and "unexplained" in res.odometry["why"], res.odometry
    ce = corner_error(res.H, truth, size)
    assert ce.median_px <= 0.5 and ce.max_px <= 2.0, ce
    # AND the same odometry the right way up is used
    res = align_group(H0, corr, size, focal_px=618.0, pair_H=pair_H, odometry=_simulated_odometry(truth, size, 1))
    assert res.odometry["used"] and res.odometry["displacements"] == len(frames) - 1, res.odometry


@pytest.mark.parametrize("focal", [True, False], ids=["focal", "self-calibrated"])
def test_pose_model_places_the_sweep_on_the_wall(synthetic_sweep, focal):
    # GIVEN a 3-pass sweep with yaw, scale and tilt jitter and exact ground truth
    folder, H_gt, path, _ = synthetic_sweep
    reg = register(FolderSource(folder), params=RegisterParams(focal_px=path.focal_px if focal else None))
    g = reg.groups[0]
    # THEN the pose model is kept, and the self-calibrated focal length is near the truth
    assert g.model == "pose", g.note
    assert abs(g.camera.f / path.focal_px - 1) < (1e-9 if focal else 0.15)
    # AND every corner is within a pixel of the wall after one similarity
    ce = corner_error(g.H, H_gt, path.frame_wh)
    assert ce.n_frames == len(H_gt)
    assert ce.median_px < 0.5 and ce.max_px < 2.0, ce


def test_pose_model_beats_free_homographies_without_the_focal_length(synthetic_sweep):
    folder, H_gt, path, _ = synthetic_sweep
    free = register(FolderSource(folder), params=RegisterParams(align=AlignParams(pose_model=False))).groups[0]
    pose = register(FolderSource(folder)).groups[0]
    assert free.model == "homography" and pose.model == "pose"
    e_free, e_pose = (corner_error(g.H, H_gt, path.frame_wh) for g in (free, pose))
    assert e_pose.max_px < 0.5 * e_free.max_px, (e_pose, e_free)


def test_a_focal_length_that_contradicts_the_images_is_reported(synthetic_sweep, tmp_path):
    # GIVEN the sweep and a focal length 3x too long
    folder, H_gt, path, _ = synthetic_sweep
    out = run_mosaic(FolderSource(folder), tmp_path, params=MosaicParams(register=RegisterParams(focal_px=3 * path.focal_px)))
    # THEN one line names the problem, and the self-calibrated pose model still places every frame
    assert out.problems and "contradicts the images" in out.problems[0] and "900" in out.problems[0]
    doc = json.loads((tmp_path / "mosaic.json").read_text())
    assert len(doc["frames"]) == len(H_gt)
    assert {f["model"] for f in doc["frames"]} == {"pose"}
    assert abs(doc["groups"][0]["camera"]["focal_px"] / path.focal_px - 1) < 0.15
    ce = corner_error({f["index"]: np.array(f["H"]) for f in doc["frames"]}, H_gt, path.frame_wh)
    assert ce.max_px < 2.0


def test_alignments_after_dropped_pairs_keep_the_camera_the_first_one_settled(synthetic_sweep, monkeypatch):
    # GIVEN the sweep, a focal length 3x too long, and a pair outlier cut tight enough that the first
    # alignment drops pairs (so the groups are aligned again)
    import inspect_pipe.mosaic._align as align_mod
    folder, H_gt, path, _ = synthetic_sweep
    fits = []
    original = align_mod.fit_pose_model

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        fits.append((kwargs["self_calibrate"], args[3]))
        return out

    monkeypatch.setattr(align_mod, "fit_pose_model", spy)
    reg = register(FolderSource(folder), params=RegisterParams(focal_px=3 * path.focal_px, pair_outlier_px=0.2))
    g = reg.groups[0]
    # THEN self-calibration ran once, in the first alignment, and the later ones fitted its camera held fixed
    first_self = [k for k, (self_cal, _) in enumerate(fits) if self_cal]
    later = fits[first_self[-1] + 1:]
    assert len(first_self) == 1 and len(later) >= 1, fits
    assert all(not self_cal and f0 == pytest.approx(g.camera.f, rel=0.05) for self_cal, f0 in later), fits
    # AND the group keeps the pose model, the contradiction stays reported, and the frames sit on the wall
    assert g.model == "pose" and "contradicts the images" in g.note and "900" in g.note
    assert abs(g.camera.f / path.focal_px - 1) < 0.15
    ce = corner_error(g.H, H_gt, path.frame_wh)
    assert ce.n_frames == len(H_gt) and ce.max_px < 2.0, ce


def test_a_self_calibrated_fit_is_given_up_only_when_far_off_and_stalled():
    # GIVEN the stall rule (5 evaluations, 4x the acceptance limit, 1 % progress) with a limit of 1 px
    from types import SimpleNamespace

    from inspect_pipe.mosaic._align import _stalled

    params = AlignParams()
    assert (params.stall_nfev, params.stall_ratio, params.stall_progress) == (5, 4.0, 0.01)

    def run(rms_by_nfev, give_up_px=4.0):
        cb = _stalled(give_up_px, params)
        for nfev, rms in rms_by_nfev:
            # residuals (i->j x, y, j->i x, y) whose larger transfer error is ``rms`` for every correspondence
            fun = np.tile([rms, 0.0, 0.0, 0.5 * rms], 10)
            try:
                cb(SimpleNamespace(fun=fun, nfev=nfev))
            except StopIteration:
                return nfev
        return None

    # THEN a fit sitting at 46 px (the NPU drone scene) stops once 5 evaluations show no progress
    assert run([(n, 46.6 - 0.001 * n) for n in range(1, 30)]) == 6
    # AND a far-off fit that is still moving (a focal length 3x off, a long sweep's chained start) goes on
    assert run([(n, 60.0 * 0.8 ** n) for n in range(1, 30)]) is None
    # AND a stalled fit within 4x of the limit goes on to be judged by its fit
    assert run([(n, 3.9) for n in range(1, 30)]) is None


def test_self_calibration_from_a_drifted_chain_restarts_from_the_fixed_focal_fit():
    # GIVEN the global step's input of a validation sweep whose chained layout has drifted (fixture README):
    # self-calibration started from that chain crawls to 0.70 px RMS, over the 0.67 px the pose model must meet
    from pathlib import Path

    from inspect_pipe.mosaic._align import align_group

    z = np.load(Path(__file__).parents[1] / "fixtures" / "mosaic" / "drifted_chain_vt130.npz")
    frames = [int(f) for f in z["frames"]]
    H0 = dict(zip(frames, z["H0"]))
    corr = Correspondences(z["fi"], z["fj"], z["p"].astype(float), z["q"].astype(float))
    pair_H = {(int(a), int(b)): h for (a, b), h in zip(z["pairs"], z["pair_H"])}
    size = tuple(int(v) for v in z["size"])
    res = align_group(H0, corr, size, pair_H=pair_H)
    # THEN the fit restarted from the fixed-focal pose model is kept, near the true focal length (618 px)
    assert res.model == "pose", res.note
    assert abs(res.camera.f / 618.0 - 1) < 0.1
    # AND every corner is within the self-calibrated goal (the free homographies it fell back to: 12 / 76 px)
    ce = corner_error(res.H, dict(zip(frames, z["H_true"])), size)
    assert ce.n_frames == len(frames)
    assert ce.median_px < 1.0 and ce.max_px < 4.0, ce


def _global_step_input(name: str):
    from pathlib import Path

    z = np.load(Path(__file__).parents[1] / "fixtures" / "mosaic" / name)
    frames = [int(f) for f in z["frames"]]
    corr = Correspondences(z["fi"].astype(int), z["fj"].astype(int), z["p"].astype(float), z["q"].astype(float))
    pair_H = {(int(a), int(b)): h for (a, b), h in zip(z["pairs"], z["pair_H"])}
    return frames, dict(zip(frames, z["H0"])), corr, pair_H, tuple(int(v) for v in z["size"]), dict(zip(frames, z["H_true"]))


def test_frames_at_a_pass_end_held_by_two_pairs_are_placed_within_the_goal_with_the_focal_length():
    # GIVEN the global step's input of a validation sweep over a texture-poor wall (fixture README): the frames at the
    # end of its third pass are held by two or three neighbour pairs only, with 40 correspondences a pair
    from inspect_pipe.mosaic._align import align_group

    frames, H0, corr, pair_H, size, truth = _global_step_input("pass_end_vt173.npz")
    res = align_group(H0, corr, size, focal_px=618.0, pair_H=pair_H)
    assert res.model == "pose", res.note
    # THEN every corner is within the goal with the focal length given (12 correspondences a pair and at most 40
    # evaluations left the pass's last frame 36.8 px off: the adjustment stopped unconverged and was accepted on its RMS)
    ce = corner_error(res.H, truth, size)
    assert ce.n_frames == len(frames)
    assert ce.median_px <= 0.5 and ce.max_px <= 2.0, ce


def test_a_pose_fit_stopped_by_its_evaluation_cap_leaves_weakly_held_frames_off():
    # GIVEN the same input with the earlier settings: 12 correspondences a pair and at most 40 evaluations
    from dataclasses import replace

    from inspect_pipe.mosaic._align import AlignParams, align_group

    frames, H0, corr, pair_H, size, truth = _global_step_input("pass_end_vt173.npz")
    early = replace(AlignParams(), pose_points_per_pair=12, pose_max_nfev=40)
    res = align_group(H0, corr, size, focal_px=618.0, pair_H=pair_H, params=early)
    # THEN the fit passes its RMS test and is kept, yet frames at the pass's end are far off: why the cap was raised
    assert res.model == "pose"
    assert corner_error(res.H, truth, size).max_px > 3.0


def test_self_calibration_starts_from_the_pair_seed_where_the_chain_has_no_focal_minimum():
    # GIVEN the same sweep without its focal length: the metric-rectification scan of its drifted chain is lowest at
    # the end of the plausible range (154 px, true 618); self-calibration from there ran off to 153 px, the pose
    # model was rejected and free homographies ended 21.9 / 153.8 px off (tools/mosaic_validation.py: 0.53 / 3.21 px
    # from the pair seed; the whole fit is too slow for the suite)
    from inspect_pipe.mosaic._align import AlignParams, initial_focal

    frames, H0, corr, pair_H, size, truth = _global_step_input("pass_end_vt173.npz")
    lo, hi = (r * max(size) for r in AlignParams().focal_range)
    f0 = initial_focal(H0, size, (size[0] / 2, size[1] / 2), pair_H, AlignParams())
    # THEN the start is inside the plausible range, not at its end
    assert lo * 1.01 <= f0 <= hi / 1.01


def test_the_pose_adjustment_keeps_its_correspondences_within_the_budget(monkeypatch):
    # GIVEN 100 pairs of 40 correspondences and a budget of 1,500 correspondences, at least 12 a pair
    import inspect_pipe.mosaic._align as align

    seen = []

    def spy(H, corr, cam, **kw):
        seen.append(np.bincount(corr.fi * 1000 + corr.fj).max())
        return H, cam, 1, True

    monkeypatch.setattr(align, "adjust_poses", spy)
    rng = np.random.default_rng(0)
    fi = np.repeat(np.arange(100), 40)
    corr = Correspondences(fi, fi + 1, rng.uniform(0, 500, (4000, 2)), rng.uniform(0, 500, (4000, 2)))
    H0 = {f: np.eye(3) for f in range(101)}
    for budget, per_pair in ((1_500, 15), (400, 12), (100_000, 40)):
        seen.clear()
        align.fit_pose_model(H0, corr, (512, 384), 600.0, (256, 192), self_calibrate=False,
                             params=AlignParams(pose_points_budget=budget))
        # THEN each pair keeps budget / pairs, never fewer than 12 nor more than 40
        assert seen == [per_pair], (budget, seen)
