"""The room moving between a zone's frames, and the laser-off frames turned back onto the lit ones.

The lasers ride with the camera: their spots stay where the surface's depth puts them however the
camera turns. The room does not. A rig on a robot that turns, worn by someone walking, or on a head
still ringing after a move sees the room slide between its laser-on and laser-off frames, and the
difference keeps the room's edges. They raise the noise that spots must stand above and pull the
centroids of those that do: on the office, the off frame turned 0.1° (1 px) lost 6 of 60 `ok`
zones and doubled the mean error; turned 0.5–2°, a third of them were lost.

`Steadier` tells, for about 20 µs a pair, whether a laser-off frame moved against its laser-on
frame, from a sparse grid of pixels away from the laser paths: a Lucas–Kanade step at baselines of
1 and 4 px against what the pixel noise alone gives (sub-pixel ringing to a few pixels), and the
difference's energy against the frames' own steps from pixel to pixel (a turn larger than the
texture's grain). Where one did, it finds how the camera turned between them (a rotation of the
rays through the lens: the homography K·R·K⁻¹ where the lens has no distortion; it moves the whole
room, parallax aside), coarse by phase correlation and then by Gauss–Newton on the same grid made
dense, and turns the off frame back onto the on frame. A lit frame is never moved: its spots are
where the ranging reads them. Pure (numpy and OpenCV).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from edge.rig import CameraModel

# The gate: baselines (px) of the gradients that the difference is set against; a pair moved where
# the difference that one explains is this many times the noise's (χ² with 2 degrees of freedom:
# 14 at 1 in 1000). Still frames of the office came to at most 31 over 90 pairs; turned 0.02°
# (0.2 px), at least 176. (A third baseline, 12 px, found no turn that these and the energy below
# missed, on the office turned 0.02–2°, and cost a fifth of the gate.)
GATE_BASELINES_PX = (1, 4)  # (the first 1 px: its neighbours ahead are the next pixels right and down)
GATE_CHI2 = 100.0
# ... and where the difference's energy is this many times that of neighbouring pixels' differences
# within the frames (still frames: 0.02–0.7 on the office and kitchen, to 1.1 through the Pi
# camera's ISP, whose noise neighbouring pixels share; turned 2°, 1.8–31).
GATE_ENERGY = 2.0
GATE_SAMPLES = 500  # (about: a grid over the picture, less the laser paths)
GATE_MARGIN_PX = 4  # (a gate sample is at least this far from the picture's edge: its farthest neighbour)
# Pixels at least this far from every laser path only are read by the gate and the fit (spots are
# not the room).
PATH_CLEARANCE_PX = 12
# The fit: a grid of this step (px) over the picture; Gauss–Newton steps, at most FIT_STEPS, first on
# every COARSE_EVERY-th row and column of it until a step moves the picture's centre by less than
# COARSE_STEADY_PX (a step's cost is the samples it reads, and far from the turn a sparse grid
# leads as well), then on the whole grid until a step moves it by less than STEADY_PX.
FIT_STEP_PX = 8
FIT_STEPS = 8
COARSE_EVERY = 2
COARSE_STEADY_PX = 0.1
STEADY_PX = 0.01
PHASE_LEVELS = (1, 2, 3)  # the pyramid levels whose phase correlation may start the fit (surest first)
AGREE_PX = 3.0  # (full-size px: the smallest level's shift is known to about a pixel of its own, 8 of these)
# A turn that moves no pixel of the picture by this much is no turn: the frames are left as they are.
LEAST_SHIFT_PX = 0.05
# A turn is taken where it explains this many times the noise's share of the unturned difference
# (the fitted samples' squared difference that it took away, over the residual's per sample: χ²
# with 3 degrees of freedom, past any chance), and moves no pixel by more than this share of the
# picture's side (phase correlation's reach, and more than a frame's turn of anything that ranges
# while it moves).
TURN_CHI2 = 50.0
TURN_EXPLAINS = 0.85  # ... and leaves at most this share of the unturned difference's RMS
TURN_SURE = 0.5  # a turn that leaves less than this share is taken without trying the other starts
MAX_SHIFT = 0.25
RAY_TOLERANCE_PX = 0.01  # a pixel's ray leads back to it within this, or it has none (Steadier._rays)
MAP_STEP_PX = 8  # (a distorted lens's turn is mapped on a grid of this step: Steadier.turned_back)


@dataclass(frozen=True)
class Turn:
    """How the camera turned from a laser-on frame to a laser-off frame: `rotation` (3 × 3, the on
    frame's rays to the off frame's), `shift_px` how far it moved the picture (its centre or a
    corner, whichever most), and
    `residual`, the fit's RMS difference (full scale) where the room was read."""

    rotation: np.ndarray
    shift_px: float
    residual: float


def _grid(cam: CameraModel, clear: np.ndarray, step: int, margin: int) -> tuple[np.ndarray, np.ndarray]:
    """(v, u) of a grid of `step` px inside `margin` of the edges, where `clear` (H × W bool) holds."""
    v, u = np.mgrid[margin : cam.height - margin : step, margin : cam.width - margin : step]
    keep = clear[v, u]
    return v[keep].astype(np.intp), u[keep].astype(np.intp)


class Steadier:
    """Laser-off frames turned back onto laser-on frames, for one camera: `paths` (each (N, 2) u, v)
    are the laser paths, whose pixels neither the gate nor the fit reads."""

    def __init__(self, cam: CameraModel, paths: Sequence[np.ndarray]) -> None:
        self.cam = cam
        clear = np.ones((cam.height, cam.width), np.uint8)
        for path in paths:
            pts = np.round(np.asarray(path, np.float64)).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(clear, [pts], False, 0, thickness=2 * PATH_CLEARANCE_PX + 1)
        self._clear = clear.astype(bool)
        step = max(8, int(math.sqrt(cam.width * cam.height / GATE_SAMPLES)))
        v, u = _grid(cam, self._clear, step, GATE_MARGIN_PX + 1)
        self._gate_n = v.size
        # Rows of a gather: the grid's pixels; their neighbours ahead at each baseline, along u then
        # v; then those behind, alike (so that ahead less behind is one subtraction of two blocks, and
        # the first baseline's neighbours ahead, 1 px, are the next pixels right and down).
        ahead = [(b, 0) for b in GATE_BASELINES_PX] + [(0, b) for b in GATE_BASELINES_PX]
        offsets = [(0, 0)] + ahead + [(-du, -dv) for du, dv in ahead]
        self._gate_pixels = np.concatenate([(v + dv) * cam.width + (u + du) for du, dv in offsets])
        self._gate_index: dict[int, np.ndarray] = {}
        fv, fu = _grid(cam, self._clear, FIT_STEP_PX, 2)
        # (their rays, through the lens: a wide webcam's barrel makes a turn of 6 px move the
        # picture's corners a pixel less than its centre, which no homography follows; pixels
        # without one are not read)
        rays, through = self._rays(fu, fv)
        self._fit_v, self._fit_u, self._fit_rays = fv[through], fu[through], rays[through]
        fv, fu = self._fit_v, self._fit_u
        self._coarse = ((fv - 2) // FIT_STEP_PX % COARSE_EVERY == 0) & ((fu - 2) // FIT_STEP_PX % COARSE_EVERY == 0)
        self._coarse_rays = self._fit_rays[self._coarse]
        self._k = np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]])
        self._k_inv = np.linalg.inv(self._k)
        self._windows: dict[tuple[int, int], np.ndarray] = {}
        # A distorted lens's frames are turned back through a map of the turn, worked out on a grid
        # of MAP_STEP_PX and interpolated between (a 640-px webcam's barrel, k1 = −0.2, turned 5 px:
        # 0.008 px from the map worked out at every pixel, at a fifth of its cost): each pixel's
        # place on that grid, and the grid's rays.
        self._map_grid: tuple[np.ndarray, np.ndarray] | None = None
        if cam.distorted:
            gv, gu = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float32)
            self._map_grid = (gu / MAP_STEP_PX, gv / MAP_STEP_PX)
            nv, nu = (cam.height - 1) // MAP_STEP_PX + 2, (cam.width - 1) // MAP_STEP_PX + 2
            cv_, cu_ = np.mgrid[0:nv, 0:nu].astype(np.float64) * MAP_STEP_PX
            self._map_pixels = np.column_stack([cu_.ravel(), cv_.ravel()])
            self._map_rays, self._map_through = self._rays(cu_.ravel(), cv_.ravel())
            self._map_shape = (nv, nu)
        # The picture's centre and corners, whose move is a turn's size (`_shift_px`), and their rays.
        w, h = cam.width - 1, cam.height - 1
        self._shift_points = np.array([[cam.cx, cam.cy], [0, 0], [w, 0], [0, h], [w, h]], np.float64)
        self._shift_rays = self._rays(self._shift_points[:, 0], self._shift_points[:, 1]) if cam.distorted else None

    def _rays(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rays (n, 3) (x, y, 1) through pixels (`u`, `v`), their lens's distortion undone, and
        which of them have one (n,): a strong barrel's distorted radius peaks and folds back, and a
        picture's corners may lie past the peak (800 px at f = 538 px with k1 = −0.2), where no ray
        leads and the undoing wanders off (RAY_TOLERANCE_PX)."""
        cam = self.cam
        xd = np.column_stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy])
        xn = cam.undistort(xd)
        with np.errstate(invalid="ignore", over="ignore"):
            through = np.abs(cam.distort(xn) - xd).max(axis=1) * max(cam.fx, cam.fy) < RAY_TOLERANCE_PX
        return np.column_stack([xn, np.ones(len(xn))]), through

    def _through_lens(self, rotation: np.ndarray, uv: np.ndarray, rays: np.ndarray, through: np.ndarray
                      ) -> np.ndarray:
        """Where `rotation` carries pixels `uv` (n, 2), whose `_rays` are `rays` and `through`: through
        the lens, and as by the homography where no ray leads."""
        out = self.cam.project(rays @ rotation.T)
        if not through.all():
            out[~through] = self._by_homography(rotation, uv[~through])
        return out

    # --- the gate ---------------------------------------------------------------------------------

    def _gather(self, image: np.ndarray, neighbours: bool = True) -> np.ndarray:
        """The gate's samples of `image`'s read plane (red of BGR), float32: the grid's pixels and,
        with `neighbours`, theirs at each baseline ((1 + 4·baselines, samples); else (1, samples))."""
        channels = image.shape[2] if image.ndim == 3 else 1
        index = self._gate_index.get(channels)
        if index is None:
            index = self._gate_pixels * channels + (2 if channels == 3 else 0)
            self._gate_index[channels] = index
        if not neighbours:
            index = index[: self._gate_n]
        values = image.reshape(-1).take(index, mode="wrap").astype(np.float32)
        return values.reshape(-1, self._gate_n)

    def moved(self, lit: np.ndarray, dark: np.ndarray) -> bool:
        """Did the room move between `lit` and `dark`, by what it leaves in their difference?
        (`_score` over either of its lines.)"""
        return _moving(self._score(lit, dark))

    def _score(self, lit: np.ndarray, dark: np.ndarray) -> tuple[float, float]:
        """What the room's moving between `lit` and `dark` leaves in their difference: its energy
        over that of neighbouring pixels' differences within the frames, and the largest share of
        it that the room's gradient at one baseline explains, over the noise's share (χ²).

        Two tests. A turn of a pixel or so leaves the room's gradient times the shift: the
        difference that the gradient at some baseline explains is GATE_CHI2 times the noise's
        share. A bigger one leaves two unrelated views of the room's texture: the difference
        (less the room light's change, fitted) is GATE_ENERGY times the frames' own differences
        between neighbouring pixels, which still frames' noise alone brings to about 1."""
        if self._gate_n < 16:
            return 0.0, 0.0
        a, b = self._gather(lit), self._gather(dark, neighbours=False)[0]
        nb = len(GATE_BASELINES_PX)
        n = float(self._gate_n)
        # The frames' samples less their means (so that no large sums cancel below), and every sum
        # the tests need by one product of these rows with themselves: those two, the lit frame's
        # gradients at each baseline (u, then v), and its steps to the next pixel right and down.
        rows = np.empty((4 + 2 * nb, self._gate_n), np.float32)
        np.subtract(a[0], np.float32(float(np.add.reduce(a[0])) / n), out=rows[0])
        np.subtract(b, np.float32(float(np.add.reduce(b)) / n), out=rows[1])
        np.subtract(a[1 : 1 + 2 * nb], a[1 + 2 * nb :], out=rows[2 : 2 + 2 * nb])
        np.subtract(a[1 : 2 + nb : nb], a[0], out=rows[2 + 2 * nb :])
        g = rows.dot(rows.T).tolist()
        # b − (gain·a + offset), least squares: a flickering lamp is not motion
        vaa, vab, vbb = g[0][0], g[0][1], g[1][1]
        gain = vab / vaa if vaa > 0.0 else 1.0
        energy = max(vbb - gain * vab, 0.0) / n  # the fit's residual, per sample
        last = 2 + 2 * nb
        nearby = (g[last][last] + g[last + 1][last + 1]) / (2.0 * n)
        noise2 = max(energy, 1e-12)
        best = 0.0
        for k in range(nb):
            ix, iy = 2 + k, 2 + nb + k
            gx, gy = g[ix], g[iy]
            sxx, sxy, syy = gx[ix], gx[iy], gy[iy]
            # Σ gradient·(b − gain·a − offset)
            rx = gx[1] - gain * gx[0]
            ry = gy[1] - gain * gy[0]
            det = sxx * syy - sxy * sxy
            if det > 0.0:
                # rᵀ (GᵀG)⁻¹ r: the difference's energy along the gradients, over the noise's
                best = max(best, (syy * rx * rx - 2.0 * sxy * rx * ry + sxx * ry * ry) / det / noise2)
        return energy / max(nearby, 1e-12), best

    # --- the turn ---------------------------------------------------------------------------------

    @staticmethod
    def _plane(image: np.ndarray) -> np.ndarray:
        """The plane the room is matched in (red of BGR, as ranging reads), float32."""
        plane = image[..., 2] if image.ndim == 3 else image
        return plane.astype(np.float32)

    def _homography(self, rotation: np.ndarray) -> np.ndarray:
        """The picture's map from the on frame's pixels to the off frame's, for `rotation`."""
        return self._k @ rotation @ self._k_inv

    def _mapped(self, rotation: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Where `rotation` carries the on frame's pixels `uv` (n, 2) in the off frame."""
        if not self.cam.distorted:
            return self._by_homography(rotation, uv)
        return self._through_lens(rotation, uv, *self._rays(uv[:, 0], uv[:, 1]))

    def _by_homography(self, rotation: np.ndarray, uv: np.ndarray) -> np.ndarray:
        h = self._homography(rotation)
        p = uv @ h[:, :2].T + h[:, 2]
        return p[:, :2] / p[:, 2:3]

    def _shift_px(self, rotation: np.ndarray) -> float:
        """How far `rotation` moves the picture's centre or corners, whichever most (px): through the
        lens, where it is distorted."""
        points = self._shift_points
        moved = (self._by_homography(rotation, points) if self._shift_rays is None
                 else self._through_lens(rotation, points, *self._shift_rays))
        return float(np.hypot(*(moved - points).T).max())

    def turn(self, lit: np.ndarray, dark: np.ndarray) -> Turn:
        """How the camera turned from `lit` to `dark`: by Gauss–Newton on the room's pixels (three
        angles, and the room light's gain and offset between the frames: flicker), from where
        phase correlation of the whole picture puts it (coarse: a whole-pixel shift at the
        centre), and where that start does not lead to a turn, from no turn. No turn (identity,
        0 px) where neither explains the difference as a turn does (see TURN_EXPLAINS)."""
        a, b = self._plane(lit), self._plane(dark)
        rows, cols = self._fit_v, self._fit_u
        ref = a[rows, cols].astype(np.float64)
        coarse_ref = ref[self._coarse]  # (once a pair: every start's first steps read it)
        # Unturned, the room's difference (the light's gain and offset fitted alike).
        still = b[rows, cols].astype(np.float64)
        ref_c, still_c = ref - ref.mean(), still - still.mean()
        var_ref, cov = float(ref_c.dot(ref_c)), float(ref_c.dot(still_c))
        left = float(still_c.dot(still_c)) - (cov * cov / var_ref if var_ref > 0.0 else 0.0)
        unturned = math.sqrt(max(left, 0.0) / ref.size)
        gradients = (cv2.Sobel(b, cv2.CV_32F, 1, 0, ksize=3, scale=0.125),
                     cv2.Sobel(b, cv2.CV_32F, 0, 1, ksize=3, scale=0.125))
        best = None
        for du, dv in self._shifts(a, b):
            # A shift (du, dv) at the centre is a turn about the camera's y and x axes.
            start = np.array([-math.atan2(dv, self.cam.fy), math.atan2(du, self.cam.fx), 0.0])
            rotation, residual = self._fit(cv2.Rodrigues(start)[0], ref, coarse_ref, b, gradients)
            shift = self._shift_px(rotation)
            # A turn that explains no more of the difference than noise could, or only a little
            # of it (a lit frame's glow and JPEG's blocks are not the room moving: still frames'
            # fits kept 0.91–0.97 of it, turns of 0.05° or more at most 0.73), or that would
            # move the picture farther than the fit can reach (a bare wall, whose few gradients
            # let it wander), is not taken.
            if (residual < TURN_EXPLAINS * unturned
                    and ref.size * (unturned**2 - residual**2) > TURN_CHI2 * residual**2
                    and shift < MAX_SHIFT * max(self.cam.width, self.cam.height)
                    and (best is None or residual < best.residual)):
                best = Turn(rotation, shift, residual)
                if residual < TURN_SURE * unturned:
                    break  # (else another start may find a deeper fit: a 33 px turn was once taken for 20 px)
        return best or Turn(np.eye(3), 0.0, unturned)

    def _shifts(self, a: np.ndarray, b: np.ndarray) -> Iterator[tuple[float, float]]:
        """Where phase correlation puts `b` against `a` (px) at each level of the picture's
        pyramid (PHASE_LEVELS), the surest (by the correlation's peak) first, then no shift. No
        one level always finds it: whitening raises the pixel noise, which at full size
        outweighed a bare view's shapes (100 px off for a 9 px turn), and the smallest pictures
        lose a fine texture. The half-size picture costs twice as much as the smaller two
        together: where those two agree, their shifts come first, and it only where `turn` asks
        for more (no start before it led to a sure turn)."""
        half = cv2.pyrDown(a), cv2.pyrDown(b)
        small_a, small_b = half
        found = []
        for level in range(2, max(PHASE_LEVELS) + 1):
            small_a, small_b = cv2.pyrDown(small_a), cv2.pyrDown(small_b)
            if level in PHASE_LEVELS:
                found.append(self._phase(small_a, small_b, level))
        agree = len(found) > 1 and all(math.hypot(du - found[0][1], dv - found[0][2]) <= AGREE_PX
                                       for _, du, dv in found[1:])
        if agree:
            for _, du, dv in sorted(found):
                yield du, dv
            found = []
        if 1 in PHASE_LEVELS:
            found.append(self._phase(*half, 1))
        for _, du, dv in sorted(found):
            yield du, dv
        yield 0.0, 0.0

    def _phase(self, a: np.ndarray, b: np.ndarray, level: int) -> tuple[float, float, float]:
        """(−peak, du, dv): phase correlation of pyramid level `level`'s `a` and `b`, its shift
        in full-size pixels."""
        size = (a.shape[1], a.shape[0])
        window = self._windows.get(size)
        if window is None:
            window = self._windows[size] = cv2.createHanningWindow(size, cv2.CV_32F)
        (du, dv), peak = cv2.phaseCorrelate(a, b, window)
        return -peak, du * 2**level, dv * 2**level

    def _fit(self, rotation: np.ndarray, ref: np.ndarray, coarse_ref: np.ndarray, b: np.ndarray,
             gradients: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, float]:
        """Gauss–Newton from `rotation`: the turn that carries the on frame's samples `ref` (at
        `_fit_v`, `_fit_u`) onto the off frame `b` (with its `gradients`), and the RMS difference
        left. The first steps, far from the turn, are taken on a sparser grid (COARSE_EVERY, whose
        samples of the on frame are `coarse_ref`):
        a step costs as many samples as it reads, and the turn it finds there is only a start."""
        rotation, gain, offset, residual = self._steps(rotation, 1.0, 0.0, self._coarse_rays, coarse_ref, b,
                                                       gradients, COARSE_STEADY_PX)
        if not math.isfinite(residual):
            return rotation, residual
        rotation, _, _, residual = self._steps(rotation, gain, offset, self._fit_rays, ref, b, gradients, STEADY_PX)
        return rotation, residual

    def _steps(self, rotation: np.ndarray, gain: float, offset: float, rays: np.ndarray, ref: np.ndarray,
               b: np.ndarray, gradients: tuple[np.ndarray, np.ndarray],
               steady_px: float) -> tuple[np.ndarray, float, float, float]:
        """Gauss–Newton steps from `rotation` and the light's `gain` and `offset` on the samples
        whose rays are `rays` and whose values in the on frame are `ref`, until a step moves the
        picture's centre by less than `steady_px` (at most FIT_STEPS): the rotation, gain and
        offset, and the RMS difference left (inf where the turn left the picture). Each step
        turns the rays a little more (R ← exp([δ]×)·R), whose effect on a pixel is known in
        closed form: one projection a step."""
        cam = self.cam
        distorted = cam.distorted
        residual = float("inf")
        settled = False
        for step in range(FIT_STEPS + 1):
            q = rays @ rotation.T
            x, y = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
            if distorted:
                xy = cam.distort(np.column_stack([x, y]))
                mu, mv = cam.fx * xy[:, 0] + cam.cx, cam.fy * xy[:, 1] + cam.cy
            else:
                mu, mv = cam.fx * x + cam.cx, cam.fy * y + cam.cy
            inside = (mu >= 1) & (mu <= cam.width - 2) & (mv >= 1) & (mv <= cam.height - 2)
            kept = np.count_nonzero(inside)
            if kept < rays.shape[0] // 2:
                return rotation, gain, offset, float("inf")  # turned out of the picture
            seen_ref = ref
            if kept < inside.size:  # (the samples that stay inside only, from here on)
                x, y, mu, mv, seen_ref = x[inside], y[inside], mu[inside], mv[inside], ref[inside]
            mx, my = mu.astype(np.float32).reshape(1, -1), mv.astype(np.float32).reshape(1, -1)
            seen = cv2.remap(b, mx, my, cv2.INTER_LINEAR).ravel().astype(np.float64)
            r = seen - (gain * seen_ref + offset)
            residual = math.sqrt(float(r.dot(r)) / r.size)
            if settled or step == FIT_STEPS:
                break  # (the residual where it ended)
            sx, sy = (cv2.remap(g, mx, my, cv2.INTER_LINEAR).ravel().astype(np.float64) for g in gradients)
            # ∂(u, v)/∂δ of a ray turned by δ × itself: u = fx·x + cx with x = q_x/q_z, so
            # ∂x/∂δ = (−x·y, 1 + x², −y) and ∂y/∂δ = (−1 − y², x·y, x); then the light's gain and offset.
            gu, gv = sx * cam.fx, sy * cam.fy
            if distorted:  # (through the lens: the chain rule, its 2 × 2 Jacobian at (x, y))
                dxx, dxy, dyx, dyy = cam.distortion_jacobian(x, y)
                gu, gv = gu * dxx + gv * dyx, gu * dxy + gv * dyy
            xy = x * y
            jacobian = np.empty((5, r.size))
            jacobian[0] = -gu * xy - gv * (1.0 + y * y)
            jacobian[1] = gu * (1.0 + x * x) + gv * xy
            jacobian[2] = gv * x - gu * y
            jacobian[3] = -seen_ref
            jacobian[4] = -1.0
            # Huber weights: the spots of the lit frame, and whatever moved in the room, are not the turn.
            size = np.abs(r)
            scale = 1.4826 * _median(size) + 1e-9
            w = np.minimum(1.0, 2.0 * scale / np.maximum(size, 1e-12))
            weighted = jacobian * w
            try:
                delta = np.linalg.solve(weighted @ jacobian.T, -(weighted @ r))
            except np.linalg.LinAlgError:
                return rotation, gain, offset, float("inf")
            rotation = cv2.Rodrigues(delta[:3])[0] @ rotation
            gain, offset = gain + float(delta[3]), offset + float(delta[4])
            settled = cam.fx * float(np.hypot(delta[0], delta[1])) < steady_px
        return rotation, gain, offset, residual

    def turned_back(self, dark: np.ndarray, turn: Turn) -> np.ndarray:
        """`dark` as the on frame's camera saw it: each pixel the value of the pixel that `turn`
        carried it to (linear interpolation; the picture's edges repeated where it saw nothing)."""
        if self._map_grid is None:
            return cv2.warpPerspective(dark, self._homography(turn.rotation), (self.cam.width, self.cam.height),
                                       flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
        mapped = self._through_lens(turn.rotation, self._map_pixels, self._map_rays, self._map_through)
        coarse = mapped.reshape(*self._map_shape, 2).astype(np.float32)
        where = cv2.remap(coarse, *self._map_grid, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return cv2.remap(dark, where[..., 0], where[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def steady(self, lit: Sequence[np.ndarray], dark: Sequence[np.ndarray]) -> list[np.ndarray] | None:
        """Laser-off frames for the laser-on frames `lit`, turned back onto each, or None where none
        of `dark` moved against `lit` or no turn was taken (the frames are then read as they
        came). One off frame per on frame (the i-th on frame takes off frame i modulo their
        count), so that the on frames' mean less the off frames' leaves the spots alone however
        the room moved between them."""
        if not lit or not dark:
            return None
        paired = [dark[i % len(dark)] for i in range(len(lit))]
        scores = [self._score(on, off) for on, off in zip(lit, paired)]  # (the gate's, kept for `_steadier`)
        if not any(_moving(score) for score in scores) and not any(self.moved(lit[0], d) for d in dark[1:]):
            return None
        out, taken = [], False
        for on, off, score in zip(lit, paired, scores):
            back = self.steadied(on, off, score)[1]
            out.append(off if back is None else back)
            taken = taken or back is not None
        return out if taken else None  # (no turn taken: every off frame as it came, not one per on frame)

    def steadied(self, lit: np.ndarray, dark: np.ndarray, score: tuple[float, float] | None = None
                 ) -> tuple[Turn, np.ndarray | None]:
        """The turn from `lit` to `dark`, and `dark` turned back by it where the turn is taken (it
        moves the picture by LEAST_SHIFT_PX or more and leaves the pair steadier, `_steadier`,
        against the pair's `_score`: `score`, where the caller has it); else None."""
        t = self.turn(lit, dark)
        if t.shift_px < LEAST_SHIFT_PX:
            return t, None
        back = self.turned_back(dark, t)
        before = score if score is not None else self._score(lit, dark)
        return t, back if self._steadier(lit, back, before) else None

    def _steadier(self, lit: np.ndarray, back: np.ndarray, before: tuple[float, float]) -> bool:
        """Is `back` (an off frame turned back) steadier against `lit` than the off frame was, whose
        `_score` was `before`: less of the difference's energy, and no more of it along the room's
        gradient (or no more than the gate lets pass)? A turn fitted to what is not the room
        moving (JPEG's blocks of a still dark room: a 1 px turn, tuning-23 zone 3) turns the room
        off."""
        energy, explained = before
        energy_back, explained_back = self._score(lit, back)
        return energy_back < energy and explained_back < max(explained, GATE_CHI2)


def _median(values: np.ndarray) -> float:
    """The median of `values` (1-D), as np.median gives it, without its checks (a few µs a call
    in a fit's every step)."""
    n = values.size
    k = n // 2
    if n % 2:
        return float(np.partition(values, k)[k])
    lo, hi = np.partition(values, (k - 1, k))[k - 1 : k + 1].tolist()
    return (lo + hi) / 2.0


def _moving(score: tuple[float, float]) -> bool:
    """Does a `Steadier._score` say the room moved (either test over its line)?"""
    energy, explained = score
    return energy > GATE_ENERGY or explained > GATE_CHI2
