"""The depth read at frame i−1 as an error in the variables (issue 58, docs/semantics.md §3.10): a
track's error at frame i−1 also moves where its depth is read, and near a depth edge the read
jumps. Each accepted pose gets the expected squared shift of its members' reads within the
per-end noise, propagated through its fit, and the consistent clips and their perturbed twins are
rescored with it used in one of these ways:

    python bench/errors_in_variables.py [--form floors|cut|refit|weights|reject|gate] [--scenes 24]
                                        [--first 0] [--pool fit] [--tracks 1000] [--end-px PX]
                                        [--reject-ratio 4] [--gate 0.05] [--gate-pose region|camera]
                                        [--mover] [--models correlated depth outliers]

- ``floors``: the extra covariance A (Σ_i E[ΔD_i²] J_iᵀ g_i g_iᵀ J_i) A added to each pose's floor
  noise (A = (JᵀJ)⁻¹ on the pose's inliers, g_i the pixel shift per depth unit of member i, ΔD_i
  its read's change over offsets d ~ N(0, s² I));
- ``cut``: the same, a read whose shift would carry the point beyond ``inlier_px`` left out (it
  is an outlier then, not a bias);
- ``refit``: each pose refitted on its inliers with weights σ² / (σ² + E[shift_i²]) (σ the pose's
  residual sigma), its noise and its weight's geometry scaled by the weighted covariance's growth;
- ``weights``: the poses kept, their weight in the components (§3.5) lowered by the extra
  covariance (1 / (usual² + extra²));
- ``reject``: a pose whose extra rotation variance exceeds ``--reject-ratio`` times its floor
  noise² left out of its pair's components and floors (its pair's reason and evidence as scored);
- ``gate`` (no propagation): each pose refitted on its inliers whose depth read at frame i agrees
  with the depth a pose predicts within ``--gate`` (relative), a test of both ends' reads, its
  noise and geometry grown with its covariance; the prediction's pose is the region's own or, with
  ``--gate-pose camera``, the camera's (R_g, s t_g), which a score could apply before the search.

s, the noise at one end, is the pose's residual sigma over √2 (the tool cannot know whether a
tracker errs at one end or both), or ``--end-px``. Scenes: the random pool's (``--pool fit``: FIT's
seeds 30-99), at 2 px under iid-curr and iid-both (and ``--models``, with bench/unseen_scenes.py's
draws), each with the three perturbations at 0.25 made
on the exact clip and given the same noise draw (as bench/unseen_scenes.py); with ``--mover`` also
the scene with one moving object unmasked against the same scene masked (research.protocol's
``mover``). The JAX engine scores;
each pose's members come from the reference engine's partition (a pose whose member count differs
is left as it is). Prints, per model, each accepted pose's squared rotation error over its floor
noise² (z²) before and after, the consistent clips above 0.10 and the detections (a perturbation
above its consistent twin). Slow: per-pose NumPy fits; 24 scenes take ~3-5 min.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from unseen_scenes import CELLS, EXTRA_LEVELS_PX, noise_seed

from sgc_jax import SGCConfig, score_batch
from sgc_jax.calibration import Calibration
from sgc_jax.codes import REGION_STATUS
from sgc_jax.engines import reference
from sgc_jax.engines.reference import pose_search
from sgc_jax.engines.units import PERCENT, depth_unit
from sgc_jax.research.noise import NOISE_MODELS, add_noise
from sgc_jax.research.perturb import PERTURBATIONS, perturb_clip
from sgc_jax.research.pose_jitter import rotation_log_deg
from sgc_jax.research.protocol import random_scene
from sgc_jax.scoring.result import summarize_clip

CONFIG = SGCConfig()
OK = REGION_STATUS["ok"]
REFIT_STEPS = 5  # Gauss-Newton steps of the weighted refit (converged well before)
STEP = 1e-6  # relative depth step of the read's pixel shift per depth unit


def jacobian(X, K, R, t):
    """(pixels (n, 2), d pixels / d (left rotation vector [rad], translation) (n, 2, 6)): the
    reference engine's analytic Jacobian, per point."""
    n = len(X)
    pixels, J = pose_search.residual_jacobian(X, np.zeros((n, 2)), K, R, t)
    return pixels.reshape(2, n).T, J.reshape(2, n, 6).transpose(1, 0, 2)


def read_shift_sq(depth, prev, gain, sigma, cut=None):
    """(n,) E[(g (D(floor(p + d)) − D(floor(p))))²] over d ~ N(0, sigma² I) (half-pixel grid to
    3 sigma) for frame i−1 pixels prev (n, 2) and gains g (n,) [px per depth unit]; ``cut``: a
    shift beyond it counts 0."""
    H, W = depth.shape
    offsets = np.arange(-3 * sigma, 3 * sigma + 1e-9, 0.5) if sigma > 0 else np.zeros(1)
    dx, dy = (a.ravel() for a in np.meshgrid(offsets, offsets))
    weight = np.exp(-(dx**2 + dy**2) / (2 * max(sigma, 1e-9) ** 2))
    at = lambda u, v: depth[np.clip(np.floor(v).astype(int), 0, H - 1), np.clip(np.floor(u).astype(int), 0, W - 1)]  # noqa: E731
    read = at(prev[:, :1] + dx, prev[:, 1:] + dy)
    valid = np.isfinite(read) & (read > 0)
    shift_sq = np.where(valid, (gain[:, None] * (read - at(prev[:, 0], prev[:, 1])[:, None])) ** 2, 0.0)
    if cut is not None:
        shift_sq = np.where(shift_sq < cut**2, shift_sq, 0.0)
    return (shift_sq * weight).sum(1) / np.maximum((valid * weight).sum(1), 1e-12)


class Extra:
    """One pose's inliers, Jacobians, read directions and expected read shifts²."""

    def __init__(self, X, uv, prev, K, R, t, depth, sigma_end, cut):
        Y = X @ R.T + t
        inl = (np.linalg.norm(reference.project(K, Y) - uv, axis=1) < CONFIG.inlier_px) & (Y[:, 2] > 0)
        self.X, self.uv, self.K = X[inl], uv[inl], K
        base, self.J = jacobian(self.X, K, R, t)
        g = (reference.project(K, (self.X * (1 + STEP)) @ R.T + t) - base) / (STEP * self.X[:, 2:3])
        self.direction = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-30)
        self.shift_sq = read_shift_sq(depth, prev[inl], np.linalg.norm(g, axis=1), sigma_end, cut)
        self.A = np.linalg.pinv(np.einsum("nia,nib->ab", self.J, self.J))  # a degenerate pose's too

    def covariance(self):
        """(6, 6) the reads' covariance of the pose, A (Σ shift² J^T ĝ ĝ^T J) A."""
        Jg = np.einsum("nia,ni->na", self.J, self.direction)
        return self.A @ np.einsum("n,na,nb->ab", self.shift_sq, Jg, Jg) @ self.A

    def gate_refit(self, R, t, depth_curr, gate, predictor=None):
        """The pose refitted on the inliers whose frame-i depth read agrees with the depth that
        ``predictor`` (R, t; default the pose) predicts within ``gate`` (relative) -> (R, t, growth
        of the rotation and translation covariance's trace); as it is where fewer than 6 would remain."""
        R_p, t_p = predictor if predictor is not None else (R, t)
        H, W = depth_curr.shape
        read = depth_curr[np.clip(np.floor(self.uv[:, 1]).astype(int), 0, H - 1),
                          np.clip(np.floor(self.uv[:, 0]).astype(int), 0, W - 1)]
        keep = np.isfinite(read) & (read > 0) & (np.abs((self.X @ R_p.T + t_p)[:, 2] - read) <= gate * read)
        if keep.sum() < 6:
            return R, t, 1.0, 1.0
        X, uv = self.X[keep], self.uv[keep]
        for _ in range(REFIT_STEPS):
            base, J = jacobian(X, self.K, R, t)
            step = -np.linalg.lstsq(np.einsum("nia,nib->ab", J, J), np.einsum("nia,ni->a", J, base - uv), rcond=None)[0]
            R, t = reference.so3_exp(step[:3]) @ R, t + step[3:]
        J = jacobian(X, self.K, R, t)[1]
        Ag = np.linalg.pinv(np.einsum("nia,nib->ab", J, J))
        return R, t, np.trace(Ag[:3, :3]) / np.trace(self.A[:3, :3]), np.trace(Ag[3:, 3:]) / np.trace(self.A[3:, 3:])

    def refit(self, R, t, sigma):
        """The pose refitted with weights sigma² / (sigma² + shift²) -> (R, t, growth of the rotation
        and translation covariance's trace)."""
        w = sigma**2 / (sigma**2 + self.shift_sq)
        for _ in range(REFIT_STEPS):
            base, J = jacobian(self.X, self.K, R, t)
            step = -np.linalg.lstsq(np.einsum("n,nia,nib->ab", w, J, J), np.einsum("n,nia,ni->a", w, J, base - self.uv),
                                    rcond=None)[0]
            R, t = reference.so3_exp(step[:3]) @ R, t + step[3:]
        J = jacobian(self.X, self.K, R, t)[1]
        Aw = np.linalg.pinv(np.einsum("n,nia,nib->ab", w, J, J))
        return R, t, np.trace(Aw[:3, :3]) / np.trace(self.A[:3, :3]), np.trace(Aw[3:, 3:]) / np.trace(self.A[3:, 3:])


def rescored(clip, form: str, end_px: float | None, reject_ratio: float, gate: float, gate_pose: str,
             calibration: Calibration):
    """(SGC as shipped, SGC with the reads' errors used as ``form``, rows (n, 4): each accepted
    pose's squared rotation error [deg²] and floor noise [deg], before and after)."""
    scored = score_batch([clip]).clips[0]
    pairs = scored.pairs
    unit = depth_unit(clip, CONFIG)
    names = ("region_status", "R_local", "t_local", "region_rot_noise", "region_trans_noise", "region_rot_per_px", "region_trans_per_px",
             "local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var")
    new = {name: getattr(pairs, name).copy() for name in names}
    rows = []
    for i in range(pairs.n_pairs):
        points = reference.pair_points(clip, i + 1, CONFIG)
        R_true = clip.R_wc[i + 1] @ clip.R_wc[i].T
        R_g = reference.nearest_rotation(R_true)
        camera = (R_g, pairs.scale * (clip.t_wc[i + 1] - R_g @ clip.t_wc[i]))  # in the clip's depth units
        accepted = pairs.region_status[i] == OK
        for r in np.flatnonzero(accepted):
            member = points.region == r + 1
            if member.sum() != pairs.region_points[i, r]:
                continue
            R, t, sigma = pairs.R_local[i, r], pairs.t_local[i, r] * unit, pairs.region_sigma_px[i, r]
            extra = Extra(points.X[member], points.uv[member], points.uv_prev[member], clip.K[i + 1], R, t, clip.depth[i],
                          end_px if end_px is not None else sigma / np.sqrt(2), CONFIG.inlier_px if form == "cut" else None)
            noise = pairs.region_rot_noise[i, r]
            if form in ("refit", "gate"):
                R, t, grow_rot, grow_trans = (extra.refit(R, t, sigma) if form == "refit"
                                              else extra.gate_refit(R, t, clip.depth[i + 1], gate, camera if gate_pose == "camera" else None))
                new["R_local"][i, r], new["t_local"][i, r] = R, t / unit
                for name, grow in (("rot_noise", grow_rot), ("rot_per_px", grow_rot), ("trans_noise", grow_trans),
                                   ("trans_per_px", grow_trans)):
                    new[f"region_{name}"][i, r] *= np.sqrt(grow)
            else:
                C = extra.covariance()
                rot_deg, trans = np.degrees(np.sqrt(np.trace(C[:3, :3]))), np.sqrt(np.trace(C[3:, 3:])) / unit
                if form == "reject":
                    if rot_deg**2 > reject_ratio * noise**2:
                        new["region_status"][i, r] = REGION_STATUS["ill_conditioned"]
                elif form == "weights":
                    new["region_rot_per_px"][i, r] *= np.hypot(1.0, rot_deg / pairs.region_rot_std[i, r])
                    new["region_trans_per_px"][i, r] *= np.hypot(1.0, trans / pairs.region_trans_std[i, r])
                else:
                    new["region_rot_noise"][i, r] = np.hypot(noise, rot_deg)
                    new["region_trans_noise"][i, r] = np.hypot(pairs.region_trans_noise[i, r], trans)
            rows.append((np.sum(rotation_log_deg(pairs.R_local[i, r] @ R_true.T) ** 2), noise,
                         np.sum(rotation_log_deg(new["R_local"][i, r] @ R_true.T) ** 2), new["region_rot_noise"][i, r]))
        accepted = new["region_status"][i] == OK
        if form in ("refit", "weights", "reject", "gate") and not accepted.any():
            for name in ("local_rot_var", "local_trans_var", "global_rot_var", "global_trans_var"):
                new[name][i] = np.nan
        elif form in ("refit", "weights", "reject", "gate"):  # the components from the new poses and weights
            Rs, ts = list(new["R_local"][i][accepted]), list(new["t_local"][i][accepted])
            spread = (new["region_rot_per_px"][i][accepted], new["region_trans_per_px"][i][accepted])
            rot, trans = reference.local_variances(Rs, ts, CONFIG, spread)
            new["local_rot_var"][i], new["local_trans_var"][i] = rot, trans * PERCENT**2
            rot, trans = reference.global_variances(Rs, ts, camera[0], camera[1] / unit, CONFIG, spread)
            new["global_rot_var"][i], new["global_trans_var"][i] = rot, trans * PERCENT**2
    after = summarize_clip(clip.clip_id, dataclasses.replace(pairs, **new), calibration, compat="spec")
    return scored.sgc, after.sgc, np.array(rows, dtype=float).reshape(-1, 4)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--form", choices=("floors", "cut", "refit", "weights", "reject", "gate"), default="floors")
    parser.add_argument("--scenes", type=int, default=24)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--pool", default="fit")
    parser.add_argument("--tracks", type=int, default=1000)
    parser.add_argument("--reject-ratio", type=float, default=4.0)
    parser.add_argument("--gate", type=float, default=0.05)
    parser.add_argument("--gate-pose", choices=("region", "camera"), default="region")
    parser.add_argument("--mover", action="store_true", help="also an unmasked moving object against it masked")
    parser.add_argument("--models", nargs="*", default=[], choices=sorted(set(NOISE_MODELS) - {"iid-curr", "iid-both"}),
                        help="more noise models at 2 px (research.noise)")
    parser.add_argument("--end-px", type=float, default=None, help="the noise at one end [px] (default: sigma / √2)")
    args = parser.parse_args()
    calibration = Calibration.load("sgc-spec-2026")
    consistent: dict[str, list] = {}
    detected: dict[tuple[str, str], list] = {}
    for k in range(args.first, args.first + args.scenes):
        scene = random_scene(k, (60.0,), args.pool)
        clean = scene.clip(args.tracks)
        variants = [(kind, perturb_clip(clean, kind, 0.25, seed=scene.seed)) for kind in PERTURBATIONS]
        masked = scene.clip(args.tracks, moving=True) if args.mover else None
        cells = CELLS + tuple((model, px, 0.0) for model in args.models for px in EXTRA_LEVELS_PX)
        for j, (model, px, _) in enumerate(cells):
            if px != 2.0:
                continue
            noise = NOISE_MODELS[model].replace(px=px, depth_scale_rel=0.0)
            before, after, rows = rescored(add_noise(clean, noise, seed=noise_seed(scene.seed, j, len(CELLS))),
                                           args.form, args.end_px, args.reject_ratio, args.gate, args.gate_pose, calibration)
            consistent.setdefault(model, []).append((before, after, rows))
            line = f"{scene.name} {model} {px} px: {before:.3f} -> {after:.3f};"
            for kind, exact in variants:
                p_before, p_after, _ = rescored(add_noise(exact, noise, seed=noise_seed(scene.seed, j, len(CELLS))),
                                                args.form, args.end_px, args.reject_ratio, args.gate, args.gate_pose, calibration)
                detected.setdefault((model, kind), []).append((p_before > before, p_after > after))
                line += f" {kind} {p_before:.3f} -> {p_after:.3f}"
            if masked is not None:
                unmasked = dataclasses.replace(masked, static_mask=np.ones_like(masked.static_mask), mask_source="none")
                twin, mover = (rescored(add_noise(c, noise, seed=noise_seed(scene.seed, j, len(CELLS))), args.form,
                                        args.end_px, args.reject_ratio, args.gate, args.gate_pose, calibration)[:2]
                               for c in (masked, unmasked))
                detected.setdefault((model, "mover"), []).append((mover[0] > twin[0], mover[1] > twin[1]))
                line += f" mover {mover[0]:.3f} -> {mover[1]:.3f} (masked {twin[0]:.3f} -> {twin[1]:.3f})"
            print(line, flush=True)
    print(f"\n{args.scenes} scenes of the {args.pool} pool from {args.first}, {args.tracks} tracks, form {args.form}\n")
    print("| noise | poses | mean z² | 99th pct. z² | mean squared rotation error [deg²] | consistent clips above 0.10 "
          "| their median | detections at 0.25: warp, squeeze, depth_warp (, the mover) |")
    print("|---|---|---|---|---|---|---|---|")
    for model, items in consistent.items():
        rows = np.concatenate([r for *_, r in items])
        z_before, z_after = rows[:, 0] / rows[:, 1] ** 2, rows[:, 2] / rows[:, 3] ** 2
        before, after = np.array([b for b, *_ in items]), np.array([a for _, a, _ in items])
        hits = [np.array(detected[(model, kind)]).sum(axis=0) for kind in (*PERTURBATIONS, "mover")
                if (model, kind) in detected]
        print(f"| {model} 2 px | {len(rows)} | {z_before.mean():.2f} -> {z_after.mean():.2f} | "
              f"{np.percentile(z_before, 99):.1f} -> {np.percentile(z_after, 99):.1f} | "
              f"{rows[:, 0].mean():.2f} -> {rows[:, 2].mean():.2f} | {np.sum(before > 0.1)} -> {np.sum(after > 0.1)} of "
              f"{len(before)} | {np.median(before):.3f} -> {np.median(after):.3f} | "
              + ", ".join(f"{h[0]} -> {h[1]}" for h in hits) + f" of {len(before)} |")


if __name__ == "__main__":
    main()
