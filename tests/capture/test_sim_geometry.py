"""The simulated camera renders the wall through the exact homography it writes as truth."""

from __future__ import annotations

import math

import cv2
import numpy as np

from inspect_pipe.capture import CameraModel, Pose, wall_to_frame_homography
from inspect_pipe.capture._geometry import distort_points, rotation_from_rpy, texture_px_to_wall, undistort_points
from inspect_pipe.capture._source import default_cam_to_body
from inspect_pipe.capture.sources.sim import SimCameraParams, WallRenderer
from inspect_pipe.ship import wall_frame

CLEAN = SimCameraParams(vignetting=0.0, read_noise_dn=0.0, shot_noise_dn=0.0, paint_bgr=(0, 0, 0), other_bgr=(0, 0, 0))


def dots_texture(w=900, h=600, step=60):
    img = np.zeros((h, w, 3), np.uint8)
    centres = [(x, y) for y in range(step, h - step // 2, step) for x in range(step, w - step // 2, step)]
    for x, y in centres:
        cv2.circle(img, (x, y), 6, (255, 255, 255), -1, lineType=cv2.LINE_AA)
    return img, np.array(centres, float)


def blob_centroids(img):
    g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    n, lab, stats, cent = cv2.connectedComponentsWithStats((g > 60).astype(np.uint8))
    keep = [(i) for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] > 15
            and stats[i, cv2.CC_STAT_LEFT] > 2 and stats[i, cv2.CC_STAT_TOP] > 2
            and stats[i, cv2.CC_STAT_LEFT] + stats[i, cv2.CC_STAT_WIDTH] < img.shape[1] - 2
            and stats[i, cv2.CC_STAT_TOP] + stats[i, cv2.CC_STAT_HEIGHT] < img.shape[0] - 2]
    out = []
    for i in keep:  # intensity-weighted centroid
        ys, xs = np.nonzero(lab == i)
        wts = g[ys, xs].astype(float)
        out.append((np.sum(xs * wts) / wts.sum(), np.sum(ys * wts) / wts.sum()))
    return np.array(out)


def test_homography_matches_3d_projection_through_opencv():
    # GIVEN a tilted, yawed camera 1.4 m from the wall
    cam = CameraModel.from_hfov(752, 480, 60, dist=(-0.08, 0.02, 0.001, -0.0005, 0.0))
    R_wb = rotation_from_rpy(0.05, -0.08, 0.12)
    c2b = default_cam_to_body()
    pos = np.array([10.6, 0.3, 1.5])
    R_wc, c = R_wb @ c2b.R, pos + R_wb @ c2b.t
    H = wall_to_frame_homography(cam.K, R_wc, c, 12.0, 10.0)
    # WHEN wall points are projected by H (+ distortion) and by cv2.projectPoints of their 3D position
    uv = np.array([[4.7, 1.3], [5.0, 1.5], [5.3, 1.8], [4.6, 1.9], [5.2, 1.1]])
    q = (H @ np.c_[uv, np.ones(len(uv))].T).T
    mine = distort_points(cam, q[:, :2] / q[:, 2:])
    pts3 = np.c_[np.full(len(uv), 12.0), 5.0 - uv[:, 0], uv[:, 1]]
    rvec, _ = cv2.Rodrigues(R_wc.T)
    ref, _ = cv2.projectPoints(pts3, rvec, -R_wc.T @ c, cam.K, cam.dist)
    # THEN they agree to numerical precision
    assert np.max(np.abs(mine - ref.reshape(-1, 2))) < 1e-6
    assert np.max(np.abs(undistort_points(cam, mine) - q[:, :2] / q[:, 2:])) < 1e-3


def test_rendered_dots_land_where_the_truth_homography_says():
    # GIVEN a texture of dots at known texture pixels on the front wall, and a distorted camera
    tex, centres = dots_texture()
    mpp, origin = 0.003, (3.5, 2.6)
    cam = CameraModel.from_hfov(752, 480, 60, dist=CLEAN.dist)
    r = WallRenderer(cam, tex, mpp, origin, wall_frame("front", 12.0, 10.0), 16.0, CLEAN)
    c2b = default_cam_to_body()
    for rpy, pos in [((0.0, 0.0, 0.0), (10.6, 0.2, 1.6)), ((0.04, -0.06, 0.1), (10.8, 0.0, 1.7))]:
        R_wb = rotation_from_rpy(*rpy)
        pose = Pose(R_wb @ c2b.R, np.array(pos) + R_wb @ c2b.t)
        # WHEN the frame is rendered
        img, _ = r.render([pose], 1.0, np.random.default_rng(0))
        found = blob_centroids(img)
        # THEN each dot is found where H_wall_px_to_frame (then the lens distortion) puts it
        H = r.homography(pose) @ texture_px_to_wall(mpp, origin)
        q = (H @ np.c_[centres, np.ones(len(centres))].T).T
        pred = distort_points(cam, q[:, :2] / q[:, 2:])
        inside = (pred[:, 0] > 12) & (pred[:, 0] < 740) & (pred[:, 1] > 12) & (pred[:, 1] < 468)
        pred = pred[inside]
        assert len(pred) >= 30 and len(found) >= len(pred) - 2
        d = np.linalg.norm(pred[:, None, :] - found[None, :, :], axis=2).min(axis=1)
        assert np.median(d) < 0.25 and d.max() < 0.6, (np.median(d), d.max())


def test_motion_blur_follows_speed_times_exposure():
    # GIVEN a camera moving sideways at 0.5 m/s for a 20 ms exposure, 1.5 m from the wall
    tex, _ = dots_texture()
    cam = CameraModel.from_hfov(752, 480, 60)
    r = WallRenderer(cam, tex, 0.003, (3.5, 2.6), wall_frame("front", 12.0, 10.0), 16.0, CLEAN)
    c2b = default_cam_to_body()
    poses = [Pose(c2b.R, np.array([10.5, 0.2 - 0.01 * (k + 0.5) / 9, 1.6]) + c2b.t) for k in range(9)]
    sharp, _ = r.render([poses[4]], 1.0, np.random.default_rng(0))
    blurred, _ = r.render(poses, 1.0, np.random.default_rng(0))
    # THEN each dot's intensity spread along x grows by the variance of a box of length
    # speed * exposure * f / distance = 0.01 m * 651 px / 1.5 m = 4.34 px (b^2/12 = 1.57 px^2); not along y
    def moments(img):
        g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(float)
        n, lab, stats, _ = cv2.connectedComponentsWithStats((g > 5).astype(np.uint8))
        out = []
        for i in range(1, n):
            x, y, w, h, a = stats[i]
            if x < 5 or y < 5 or x + w > g.shape[1] - 5 or y + h > g.shape[0] - 5 or a < 30:
                continue
            win = g[y - 2:y + h + 2, x - 2:x + w + 2] * (lab[y - 2:y + h + 2, x - 2:x + w + 2] == i)
            ys, xs = np.mgrid[: win.shape[0], : win.shape[1]]
            m = win.sum()
            mx, my = (win * xs).sum() / m, (win * ys).sum() / m
            out.append((((xs - mx) ** 2 * win).sum() / m, ((ys - my) ** 2 * win).sum() / m))
        return np.array(out)

    m1, m2 = moments(sharp), moments(blurred)
    b = 0.01 * cam.K[0, 0] / (12.0 - poses[4].t[0])
    assert len(m1) == len(m2) > 20
    assert abs(np.median(m2[:, 0]) - np.median(m1[:, 0]) - b * b / 12 * (1 - 1 / 81)) < 0.2
    assert abs(np.median(m2[:, 1]) - np.median(m1[:, 1])) < 0.15
    assert math.isclose(sharp.mean(), blurred.mean(), rel_tol=0.03)
