"""The simulated vehicle's camera: renders the wall the vehicle faces at take-off (any of the four,
textured from the scenario's ``world.wall_textures``) from the true 6-DoF pose during the exposure.

A plane seen through a pinhole camera is exactly a homography, so each output pixel is mapped
(through the lens distortion) to an undistorted pixel, through the inverse wall homography to wall
metres, and sampled from the texture (a mip level chosen by the footprint, so a far wall does not
alias). On top: motion blur (the exposure integrated over sub-poses when the image moves by more
than a pixel), an on-board light falling off with distance squared, vignetting, an auto-exposure
loop, shot and read noise. The truth written with each frame (camera pose, ``H_wall_m_to_frame``)
is the mid-exposure pose that the blur is centred on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from inspect_pipe._images import imread, truncation
from inspect_pipe.capture._clock import ManualClock
from inspect_pipe.capture._geometry import (
    SIM_CALIBRATION,
    CameraModel,
    Pose,
    rotation_from_rpy,
    texture_px_to_wall,
    undistort_points,
)
from inspect_pipe.capture._source import Grab, SourceInfo, default_cam_to_body
from inspect_pipe.capture._state import TrajectoryFeed, TrueState, VehicleState
from inspect_pipe.errors import InputError
from inspect_pipe.ship import SIM_WALLS, WallFrame, wall_frame

__all__ = ["SimCameraParams", "SimSource", "WallRenderer", "trajectory_from_ticks", "tick_to_state"]


@dataclass(frozen=True)
class SimCameraParams:
    dist: tuple[float, float, float, float, float] = (-0.06, 0.015, 0.0, 0.0, 0.0)  # mild barrel, like an M12 lens
    exposure_s: float = 0.004  # initial and reference exposure
    exposure_min_s: float = 0.0002
    exposure_max_s: float = 0.02
    auto_exposure: bool = True
    target_mean: float = 0.42  # auto-exposure target (fraction of full scale)
    light_ref_distance_m: float = 1.5  # the on-board light gives texture albedo at this distance and exposure
    vignetting: float = 0.35  # relative fall-off at the image corner
    read_noise_dn: float = 1.2
    shot_noise_dn: float = 0.25  # variance per DN of signal
    max_blur_samples: int = 9
    paint_bgr: tuple[int, int, int] = (96, 110, 104)  # the wall outside the texture
    other_bgr: tuple[int, int, int] = (38, 38, 42)  # floor, side walls, open top
    seed: int = 0


# --------------------------------------------------------------------------- state from the simulator


def faced_wall(scenario) -> WallFrame:
    """The wall the vehicle faces at take-off (the nearest of the four walls' facing headings):
    the wall its camera surveys."""
    hold = scenario.world.hold
    yaw = scenario.vehicle.start_yaw_rad
    frames = [wall_frame(w, hold.length_m, hold.width_m) for w in SIM_WALLS]
    return min(frames, key=lambda f: abs(math.remainder(yaw - f.facing_heading_rad, 2 * math.pi)))


class _DeadReckoner:
    """Position estimate as the vehicle knows it (hold frame): the estimated horizontal speed
    integrated along the take-off heading, except the distance to the faced wall, which is the
    front-range estimate whenever the wall is in range; z the estimated altitude."""

    def __init__(self, start: tuple[float, float, float], yaw0: float, wall: WallFrame) -> None:
        self.p = np.array(start[:2], float)
        self.c, self.s = math.cos(yaw0), math.sin(yaw0)
        self.n = np.asarray(wall.normal[:2], float)  # into the hold
        self.o = np.asarray(wall.origin[:2], float)
        self.t: float | None = None

    def update(self, t: float, vx: float, vy: float, front_m: float | None) -> tuple[float, float]:
        if self.t is not None:
            dt = t - self.t
            self.p += np.array([self.c * vx - self.s * vy, self.s * vx + self.c * vy]) * dt
        self.t = t
        if front_m is not None:
            self.p += (front_m - float((self.p - self.o) @ self.n)) * self.n
        return float(self.p[0]), float(self.p[1])


def tick_to_state(rec, reckoner: _DeadReckoner) -> VehicleState:
    e, c = rec.out.estimate, rec.out.clearance
    x, y = reckoner.update(rec.t, e.vx_m_s, e.vy_m_s, c.front_m)
    rpy = getattr(rec, "rpy_true", (0.0, 0.0, rec.yaw_true))
    return VehicleState(
        t_s=rec.t,
        position_m=(x, y, e.altitude_m),
        dist_front_m=c.front_m,
        height_m=e.height_m,
        velocity_m_s=(e.vx_m_s, e.vy_m_s, e.vz_m_s),
        est_mode=int(e.mode),
        fsm=rec.out.fsm.value,
        inspection_mode=bool(rec.out.inspection_mode),
        truth=TrueState(tuple(rec.pos_true), rotation_from_rpy(*rpy), tuple(rec.vel_true)),
    )


def trajectory_from_ticks(scenario, ticks) -> TrajectoryFeed:
    v = scenario.vehicle
    dr = _DeadReckoner(v.start_position_m, v.start_yaw_rad, faced_wall(scenario))
    feed = TrajectoryFeed()
    for rec in ticks:
        feed.append(tick_to_state(rec, dr))
    return feed


class TrajectoryRecorder:
    """``on_tick`` callback of the flight runner that grows a :class:`TrajectoryFeed`."""

    def __init__(self, scenario) -> None:
        v = scenario.vehicle
        self._dr = _DeadReckoner(v.start_position_m, v.start_yaw_rad, faced_wall(scenario))
        self.feed = TrajectoryFeed()

    def __call__(self, rec) -> None:
        self.feed.append(tick_to_state(rec, self._dr))


# --------------------------------------------------------------------------- rendering


def _procedural_wall(width_m: float, height_m: float, seed: int, m_per_px: float = 0.01) -> np.ndarray:
    """Painted steel with blotches, for scenarios without a texture (not a defect ground truth)."""
    rng = np.random.default_rng(seed + 101)
    w, h = int(width_m / m_per_px), int(height_m / m_per_px)
    img = np.zeros((h, w, 3), np.float32)
    for sigma, amp in ((40, 30), (10, 18), (2, 10)):
        n = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), sigma)
        n /= n.std() + 1e-6
        img += amp * n[..., None] * np.array([1.0, 0.9, 0.7], np.float32)
    img += np.array([100, 112, 108], np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


class WallRenderer:
    """Pure renderer: camera model + texture -> image for given camera poses."""

    def __init__(
        self,
        camera: CameraModel,
        texture: np.ndarray,
        m_per_px: float,
        origin_uv: tuple[float, float],
        wall: WallFrame,
        hold_height_m: float,
        params: SimCameraParams = SimCameraParams(),
    ) -> None:
        self.camera, self.params = camera, params
        self.m_per_px, self.origin_uv = float(m_per_px), (float(origin_uv[0]), float(origin_uv[1]))
        self.wall = wall
        self.W, self.Hh = float(wall.width_m), hold_height_m  # the wall's extent in u and v
        self._toward_wall = -np.asarray(wall.normal, float)  # viewing direction that faces the wall
        self.levels = [texture if texture.ndim == 3 else cv2.cvtColor(texture, cv2.COLOR_GRAY2BGR)]
        while min(self.levels[-1].shape[:2]) > 64 and len(self.levels) < 8:
            self.levels.append(cv2.pyrDown(self.levels[-1]))
        w, h = camera.width, camera.height
        xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        und = undistort_points(camera, np.stack([xs.ravel(), ys.ravel()], axis=1))
        self._X = np.vstack([und.T, np.ones(und.shape[0])]).astype(np.float64)  # 3 x N undistorted pixels
        r2 = ((xs - (w - 1) / 2) ** 2 + (ys - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
        self._vignette = np.repeat((1.0 - params.vignetting * r2).astype(np.float32)[..., None], 3, axis=2)
        self._noise_bank: np.ndarray | None = None
        self.T_px_to_wall = texture_px_to_wall(self.m_per_px, self.origin_uv)
        # Fast path: render the undistorted view with warpPerspective (the homography), then apply
        # the lens distortion with one fixed remap (precomputed: undistorted pixel of every output pixel).
        lo = np.floor(und.min(axis=0)) - 2
        hi = np.ceil(und.max(axis=0)) + 2
        self._off = lo
        self._usize = (int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1)
        mx = (und[:, 0] - lo[0]).astype(np.float32).reshape(h, w)
        my = (und[:, 1] - lo[1]).astype(np.float32).reshape(h, w)
        self._dmap1, self._dmap2 = cv2.convertMaps(mx, my, cv2.CV_16SC2)
        self._ucorners = np.array([[lo[0], lo[1], 1], [hi[0], lo[1], 1], [lo[0], hi[1], 1], [hi[0], hi[1], 1]], float).T
        # the whole wall at 2 cm/px marks what is wall (vs floor, side walls, open top)
        self._wall_mpp = 0.02
        self._wall_mask = np.full((max(2, int(round(hold_height_m / 0.02))), max(2, int(round(self.W / 0.02)))), 255, np.uint8)

    def homography(self, cam_pose_world: Pose) -> np.ndarray:
        return self.wall.homography_to_frame(self.camera.K, cam_pose_world.R, cam_pose_world.t)

    def _render_one(self, cam_pose_world: Pose) -> np.ndarray:
        """Float32 BGR albedo (0..255) seen from one camera pose, without photometry."""
        H = self.homography(cam_pose_world)
        Hinv = np.linalg.inv(H)
        uvw = Hinv @ self._X
        wz = uvw[2]
        # points behind the camera map to negative depth: the wall-plane depth of a pixel ray
        depth_ok = cam_pose_world.R.T @ self._toward_wall  # wall normal in camera frame
        with np.errstate(divide="ignore", invalid="ignore"):
            u = uvw[0] / wz
            v = uvw[1] / wz
        rays = np.linalg.inv(self.camera.K) @ self._X
        in_front = (depth_ok @ rays) > 1e-9
        # footprint (texels per output pixel) at the image centre picks the mip level
        d_axis = self._axis_distance(cam_pose_world)
        s = (d_axis / self.camera.K[0, 0]) / self.m_per_px if d_axis > 0 else 1.0
        lvl = int(min(len(self.levels) - 1, max(0, math.floor(math.log2(max(s, 1.0))))))
        f = 2.0 ** lvl
        u0, v0 = self.origin_uv
        mapx = ((u - u0) / self.m_per_px) / f - 0.5
        mapy = ((v0 - v) / self.m_per_px) / f - 0.5
        shape = (self.camera.height, self.camera.width)
        mapx = np.nan_to_num(mapx, nan=-1e6, posinf=-1e6, neginf=-1e6).astype(np.float32).reshape(shape)
        mapy = np.nan_to_num(mapy, nan=-1e6, posinf=-1e6, neginf=-1e6).astype(np.float32).reshape(shape)
        img = cv2.remap(self.levels[lvl], mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=tuple(int(c) for c in self.params.paint_bgr)).astype(np.float32)
        on_wall = in_front & (u >= 0) & (u <= self.W) & (v >= 0) & (v <= self.Hh)
        img[~on_wall.reshape(shape)] = np.array(self.params.other_bgr, np.float32)
        return img

    def _axis_distance(self, cam: Pose) -> float:
        along = float(cam.R[:, 2] @ self._toward_wall)
        if along <= 1e-6:
            return -1.0
        return float(self.wall.distance(cam.t)[0]) / along

    def _render_undistorted(self, cam: Pose) -> np.ndarray | None:
        """Float32 BGR albedo of the undistorted view (with margin), or None when part of the view
        looks away from the wall plane (then the per-pixel path handles it)."""
        H = self.homography(cam)
        n_cam = cam.R.T @ self._toward_wall
        rays = np.linalg.inv(self.camera.K) @ self._ucorners
        if np.any(n_cam @ rays <= 1e-6):
            return None
        T_off = np.array([[1.0, 0.0, self._off[0]], [0.0, 1.0, self._off[1]], [0.0, 0.0, 1.0]])
        wall_from_und = np.linalg.inv(H) @ T_off  # undistorted (offset) pixel -> wall m
        d_axis = self._axis_distance(cam)
        s = (d_axis / self.camera.K[0, 0]) / self.m_per_px if d_axis > 0 else 1.0
        lvl = int(min(len(self.levels) - 1, max(0, math.floor(math.log2(max(s, 1.0))))))
        f = 2.0 ** lvl
        u0, v0 = self.origin_uv
        tex_from_wall = np.array([[1 / (self.m_per_px * f), 0, -u0 / (self.m_per_px * f) - 0.5],
                                  [0, -1 / (self.m_per_px * f), v0 / (self.m_per_px * f) - 0.5], [0, 0, 1]])
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        img = cv2.warpPerspective(self.levels[lvl], tex_from_wall @ wall_from_und, self._usize, flags=flags,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=tuple(int(c) for c in self.params.paint_bgr))
        m = self._wall_mpp
        mask_from_wall = np.array([[1 / m, 0, -0.5], [0, -1 / m, self.Hh / m - 0.5], [0, 0, 1]])
        mask = cv2.warpPerspective(self._wall_mask, mask_from_wall @ wall_from_und, self._usize,
                                   flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        img[mask == 0] = self.params.other_bgr
        return img.astype(np.float32)

    def render(self, poses: list[Pose], brightness: float, rng: np.random.Generator) -> tuple[np.ndarray, float]:
        """Average of the sub-exposure poses, with light, vignetting and noise: (uint8 BGR, mean 0..1)."""
        und = [self._render_undistorted(p) for p in poses]
        if all(u is not None for u in und):
            acc = und[0] if len(und) == 1 else np.mean(und, axis=0)
            acc = cv2.remap(acc, self._dmap1, self._dmap2, cv2.INTER_LINEAR)
        else:
            acc = np.mean([self._render_one(p) for p in poses], axis=0)
        img = cv2.multiply(acc.astype(np.float32), self._vignette, scale=float(brightness))
        p = self.params
        sigma = cv2.sqrt(cv2.add(cv2.max(img, 0.0) * p.shot_noise_dn, p.read_noise_dn ** 2))
        n = img.size
        if self._noise_bank is None:  # unit normals drawn once; each frame reads them from a random offset
            self._noise_bank = rng.standard_normal(3 * n, dtype=np.float32)
        k = int(rng.integers(0, 2 * n))
        noise = self._noise_bank[k:k + n].reshape(img.shape)
        img = cv2.add(img, cv2.multiply(sigma, noise))
        out = cv2.convertScaleAbs(cv2.max(img, 0.0))
        return out, float(out.mean()) / 255.0


# --------------------------------------------------------------------------- the source


class SimSource:
    """:class:`FrameSource` of a simulated flight. ``trajectory`` is the flight's state feed (from
    ``fly --sweep``); without one, ``open`` flies the scenario first. Software-triggered on the
    simulation clock: the exposure starts at the deadline."""

    def __init__(
        self,
        scenario,
        *,
        trajectory: TrajectoryFeed | None = None,
        clock: ManualClock | None = None,
        params: SimCameraParams | None = None,
        cam_to_body: Pose | None = None,
        camera: CameraModel | None = None,
    ) -> None:
        self.scenario = scenario
        self.camera = camera  # a calibrated camera to simulate instead of the scenario's hfov
        self.trajectory = trajectory
        self.clock = clock or ManualClock()
        self.params = params or SimCameraParams(seed=scenario.seed)
        self.cam_to_body = cam_to_body or default_cam_to_body()
        self.renderer: WallRenderer | None = None
        self._exposure = self.params.exposure_s
        self._frame_id = 0
        self._rng = np.random.default_rng(self.params.seed + 7)
        self.flight_result = None

    def open(self) -> SourceInfo:
        sc = self.scenario
        cam_cfg = sc.camera
        camera = CameraModel.from_hfov(cam_cfg.width, cam_cfg.height, cam_cfg.hfov_deg, self.params.dist, name="sim")
        camera = replace(camera, calibration=dict(SIM_CALIBRATION))
        if self.camera is not None:  # --camera: simulate that lens (scaled to the scenario's frame size if the aspect agrees)
            from inspect_pipe.capture._calibration import fit_camera

            camera = fit_camera(self.camera, cam_cfg.width, cam_cfg.height, frames="the scenario's camera frames")
        if self.trajectory is None:
            from inspect_pipe.flight.runner import run_scenario

            rec = TrajectoryRecorder(sc)
            self.flight_result = run_scenario(sc, on_tick=rec)
            self.trajectory = rec.feed
        hold = sc.world.hold
        wall = faced_wall(sc)
        tex = sc.world.texture(wall.wall.sim)
        if tex is not None:
            img = None if truncation(tex.image) else imread(str(tex.image), cv2.IMREAD_COLOR)
            if img is None:
                raise InputError(str(tex.image), f"cannot read the {wall.wall.sim} wall's texture", "a PNG or JPEG image")
            texture, mpp, origin = img, tex.m_per_px, tex.origin_uv
        else:
            texture, mpp, origin = _procedural_wall(float(wall.width_m), hold.height_m, sc.seed), 0.01, (0.0, hold.height_m)
        self.renderer = WallRenderer(camera, texture, mpp, origin, wall, hold.height_m, self.params)
        self._texture_info = (mpp, origin, tex)
        extra = {
            "scenario": sc.name,
            "scenario_file": str(sc.source) if sc.source else None,
            "seed": sc.seed,
            "hold": {"length_m": hold.length_m, "width_m": hold.width_m, "height_m": hold.height_m},
            "camera_params": {"exposure_s": self.params.exposure_s, "auto_exposure": self.params.auto_exposure,
                              "vignetting": self.params.vignetting, "read_noise_dn": self.params.read_noise_dn},
        }
        return SourceInfo("sim", f"simulated camera of scenario {sc.name}", camera, self.cam_to_body, triggered=True, extra=extra)

    def sweep_extra(self, sweep_dir: Path) -> dict:
        """What sweep.json says about the simulation: scenario, hold, the wall faced and its texture.
        Positions are in the hold frame (``odometry_frame: hold``)."""
        from inspect_pipe.capture._sweep import WallTextureInfo

        hold = self.scenario.world.hold
        wall = self.renderer.wall if self.renderer is not None else faced_wall(self.scenario)
        sim = {"scenario": self.scenario.name, "scenario_file": str(Path(self.scenario.source).resolve()) if self.scenario.source else None,
               "seed": self.scenario.seed, "hold": {"length_m": hold.length_m, "width_m": hold.width_m, "height_m": hold.height_m},
               "wall": wall.wall.sim, "wall_texture": None}
        mpp, origin, tex = self._texture_info
        if tex is not None:
            info = WallTextureInfo(Path(tex.image), mpp, tuple(origin), Path(tex.defects_mask) if tex.defects_mask else None,
                                   float(wall.width_m), hold.height_m)
            sim["wall_texture"] = info.to_json(Path(sweep_dir))
        return {"simulation": sim, "odometry_frame": "hold"}

    def _cam_pose(self, st: VehicleState) -> Pose:
        tr = st.truth
        assert tr is not None
        R = tr.R_world_body
        return Pose(R @ self.cam_to_body.R, np.asarray(tr.position_m) + R @ self.cam_to_body.t)

    def grab(self, deadline_s: float) -> Grab:
        assert self.renderer is not None and self.trajectory is not None, "open() first"
        exp = self._exposure
        t0, t1 = deadline_s, deadline_s + exp
        if t1 > self.trajectory.end_s:
            raise StopIteration
        s0, s1, smid = (self.trajectory.state_at(t) for t in (t0, t1, (t0 + t1) / 2))
        if s0 is None or s1 is None or smid is None or smid.truth is None:
            raise StopIteration
        p0, p1, pm = self._cam_pose(s0), self._cam_pose(s1), self._cam_pose(smid)
        H0, H1, Hm = (self.renderer.homography(p) for p in (p0, p1, pm))
        blur_px = _max_corner_motion(H0, H1, self.renderer.camera)
        n = int(min(self.params.max_blur_samples, max(1, math.ceil(blur_px))))
        if n == 1:
            poses = [pm]
        else:
            poses = []
            for k in range(n):
                st = self.trajectory.state_at(t0 + (k + 0.5) / n * exp)
                poses.append(self._cam_pose(st) if st is not None else pm)
        d = self.renderer._axis_distance(pm)
        light = (self.params.light_ref_distance_m / d) ** 2 if d > 0.05 else 0.0
        brightness = (exp / self.params.exposure_s) * min(light, 50.0)
        img, mean = self.renderer.render(poses, brightness, self._rng)
        if self.params.auto_exposure and mean > 0.01:
            ratio = (self.params.target_mean / mean) ** 0.6
            self._exposure = float(np.clip(exp * ratio, self.params.exposure_min_s, self.params.exposure_max_s))
        self.clock.sleep_until(t1)
        self._frame_id += 1
        truth = {
            "position_m": [round(v, 6) for v in smid.truth.position_m],
            "rpy_rad": [round(v, 7) for v in _rpy(smid.truth.R_world_body)],
            "velocity_m_s": [round(v, 5) for v in smid.truth.velocity_m_s],
            "R_world_cam": pm.R.round(9).tolist(),
            "cam_center_m": pm.t.round(6).tolist(),
            "H_wall_m_to_frame": (Hm / Hm[2, 2]).tolist(),
            "H_wall_px_to_frame": _norm(Hm @ self.renderer.T_px_to_wall).tolist() if self._texture_info[2] is not None else None,
            "motion_blur_px": round(blur_px, 3),
        }
        return Grab(
            image=img, t_exposure_start_s=t0, exposure_s=exp, t_host_s=t1, frame_id=self._frame_id,
            t_device_s=t0, gain=1.0, state=smid, truth=truth,
        )

    def close(self) -> None:
        pass


def _norm(H: np.ndarray) -> np.ndarray:
    return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else H


def _rpy(R: np.ndarray) -> tuple[float, float, float]:
    from inspect_pipe.capture._geometry import rpy_from_rotation

    return rpy_from_rotation(R)


def _max_corner_motion(H0: np.ndarray, H1: np.ndarray, cam: CameraModel) -> float:
    """Largest image motion (px) of the frame corners and centre between two poses."""
    w, h = cam.width, cam.height
    pts = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1], [(w - 1) / 2, (h - 1) / 2, 1]], float).T
    try:
        M = H1 @ np.linalg.inv(H0)
    except np.linalg.LinAlgError:
        return 0.0
    q = M @ pts
    if np.any(q[2] <= 1e-9):
        return 0.0
    q = q[:2] / q[2]
    return float(np.max(np.linalg.norm(q - pts[:2], axis=0)))


def capture_flight(scenario, trajectory: TrajectoryFeed, sweep_dir: str | Path, *, params: SimCameraParams | None = None,
                   image_format: str = "png", overwrite: bool = False, live=None):
    """The camera's sweep of a flown scenario (``fly --sweep``): every frame at the scenario's
    camera rate on the simulation clock, for the whole flight. ``live``: a
    :class:`inspect_pipe.mosaic.LiveFeed` that gets every frame (simulated time waits for it)."""
    from inspect_pipe.capture._service import CaptureConfig, run_capture

    clock = ManualClock(0.0)
    src = SimSource(scenario, trajectory=trajectory, clock=clock, params=params)
    cfg = CaptureConfig(rate_hz=scenario.camera.fps, image_format=image_format, time_base="simulation_s",
                        overwrite=overwrite, wait_for_writer=True)  # simulated time waits for the writer: no drops
    return run_capture(src, sweep_dir, clock=clock, config=cfg, on_frame=None if live is None else live.tap(block=True))
