"""Build and execute the research notebooks, so their stored outputs are reproducible.

    python notebooks/build.py                 # every notebook
    python notebooks/build.py 02_sensitivity  # some of them

Each notebook's cells are defined below; they are written with nbformat and executed top to
bottom in a fresh kernel with nbclient, in this folder, and stored with their outputs.
``tests/test_notebooks.py`` checks that the stored code is the code below and executes every
notebook again. The notebooks use only the public API (``sgc_jax``, ``sgc_jax.codes``, and
``sgc_jax.research``'s ``plot``, ``synth``, ``diagnostics``, ``compare`` and ``perturb``; ``sgc_jax.stats``).
"""

from __future__ import annotations

import os
import sys
import textwrap
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TIMEOUT_S = 600  # per cell

SETUP = """\
import warnings

warnings.filterwarnings("ignore", message="IProgress not found")  # tqdm.auto looks for ipywidgets

import matplotlib
import numpy as np
import pandas as pd

import sgc_jax
from sgc_jax.research import plot
from sgc_jax.research.synth import synth_clip

matplotlib.rcParams["figure.dpi"] = 80  # small stored figures
pd.set_option("display.precision", 4)
pd.set_option("display.width", 160)
# One small scene recipe for every notebook: 2 planar layers and 4 static spheres in front of a back
# wall, 8 frames of 96x128 pixels, 1024 tracks per frame pair (the demo corpus's shape).
SCENE = dict(n_layers=2, static_spheres=4, n_frames=8, height=96, width=128, n_tracks=1024)
# Clips are read 4 at a time ahead of the scorer; they share one padded shape, so the JAX engine
# compiles once (once per machine: compiled programs are kept on disk).
CHUNK = 4"""
SETUP_WITHOUT_NUMPY = SETUP.replace("import numpy as np\n", "")  # for the notebooks that use no NumPy


def _md(text: str) -> tuple[str, str]:
    return "markdown", textwrap.dedent(text).strip("\n")


def _code(text: str) -> tuple[str, str]:
    return "code", textwrap.dedent(text).strip("\n")


def _timing(text: str) -> tuple[str, str]:
    """A code cell whose output is a time: tagged ``timing``, so tests run it but do not compare it."""
    return "timing", textwrap.dedent(text).strip("\n")


def _cpu_rounded(text: str) -> tuple[str, str]:
    """A code cell whose output follows the CPU's float rounding through a long descent: tagged
    ``cpu-rounding``, so tests run it but do not compare it."""
    return "cpu-rounding", textwrap.dedent(text).strip("\n")


ENGINE_NOTE = _md("""
    **Compilation.** The default `engine="jax"` pads clips to a shape bucket (frames, pixels,
    tracks) and compiles its programs once per bucket: the first call of a new shape takes about a
    minute on a laptop CPU, later calls take about a second per clip. Compiled programs are kept on
    disk (`~/.cache/sgc_jax`, docs/semantics.md §7.1), so a later session loads them in seconds.
    `engine="reference"` (NumPy + OpenCV) needs no compilation but is slower per clip.
""")

QUICKSTART = [
    _md("""
        # Quickstart: score a few clips

        SGC asks whether a video's static background behaves like one rigid 3D world seen by one
        moving camera. Its inputs are estimator outputs (camera poses and intrinsics, depth, point
        tracks, moving-object masks) computed beforehand; here they come from `sgc_jax.research.synth`,
        synthetic scenes whose geometry is exact. Lower SGC is better.
    """),
    _code(SETUP_WITHOUT_NUMPY),
    _md("""
        ## Four clips

        A rigid scene; a scene with two moving spheres, masked as moving-object segmentation would
        (`moving-masked`) and unmasked (`moving-unmasked`: their motion leaks into the "static"
        background); and the rigid scene with a *squeeze* perturbation (the tracks are compressed
        vertically, more in later frames) at severity 0.5.
    """),
    _code("""\
        clips = [
            synth_clip(seed=0, clip_id="rigid", group="rigid", **SCENE),
            synth_clip(seed=1, clip_id="moving-masked", group="moving", moving_objects=2, **SCENE),
            synth_clip(seed=1, clip_id="moving-unmasked", group="moving", moving_objects=2, with_mask=False, **SCENE),
        ]
        clips.append(sgc_jax.perturb_clip(clips[0], "squeeze", 0.5))
        pd.DataFrame([{"clip_id": c.clip_id, "frames": c.n_frames, "H x W": c.image_size, "tracks per pair": c.n_tracks,
                       "mask": c.mask_source} for c in clips])"""),
    _md("""
        ## Score them

        `score_batch` takes paths, directories, globs, mappings of arrays or `Clip` objects and
        returns a `BatchResult`: one row per clip with the SGC, its five components and
        diagnostics. Units (docs/semantics.md §4): rotation variances in deg², translation variances
        in (% of D)², D being the clip's median static depth, and the depth error in % of the depth;
        scaling a clip's depth or camera translations changes none of them.
    """),
    ENGINE_NOTE,
    _code("""\
        result = sgc_jax.score_batch(clips, chunk_size=CHUNK)
        result.to_pandas()[["clip_id", "group", "status", "sgc", "sgc_lo", "sgc_hi", *sgc_jax.COMPONENTS,
                            "n_pairs_scored"]]"""),
    _md("""
        The rigid clip's pose variances vanish to float precision, and its SGC is 0: the default
        calibration, `sgc-spec-2026`, counts a pose component only where it exceeds 1.25 times its
        noise floor, what the tracker's noise alone would give (`*_floor`, docs/semantics.md §3.10,
        §5.1), and puts the depth error's 0 at the 90th percentile of clean synthetic clips (§5.4):
        the depth error the forward warp leaves at occlusion edges (a few tenths of a percent, see
        `04_diagnostics`) is within it. Masked moving objects
        barely move the score; unmasked ones and the squeeze raise the local and global pose
        variances. `sgc_lo` and `sgc_hi` bracket each score at 90 %: how far it could move were the
        same world tracked again (a bootstrap over the clip's frame pairs, docs/semantics.md §5.6).

        `score_clip` scores one clip and returns a `ClipResult`; here with the reference engine. On
        this rigid clip both engines give pose variances at float32 noise (1e-11 to 1e-9: the
        engines' ratio there is noise, not a disagreement) and the same depth error to 0.1 %; how
        closely they agree on components well above zero is measured on the agreement corpus
        (docs/semantics.md §7.3):
    """),
    _code("""\
        one = sgc_jax.score_clip(clips[0], engine="reference")
        pd.DataFrame({"jax": result.clip("rigid").components, "reference": one.components})"""),
    _md("""
        ## Per-pair components over time

        Every clip keeps its per-pair arrays (`result.clip(id).pairs`); `to_pandas(pairs=True)` gives
        one row per frame pair, `pair` = i for frames i-1 → i. The squeeze grows linearly in time,
        and its pose variances tend to grow with it.
    """),
    _code("""\
        pairs = result.to_pandas(pairs=True)
        pairs[pairs.clip_id == "rigid~squeeze@0.5"][["pair", "reason", *sgc_jax.COMPONENTS, "n_regions", "n_poses"]]"""),
    _code("fig = plot.plot_pair_components(result)"),
    _md("""
        ## Depth layers over a frame

        A pair's regions are the depth layers of its first frame's static background (static mask
        and valid depth; each track's region is read where it starts, docs/semantics.md §3.2): up
        to `k_seg = 10` layers by 1-D k-means, one per 140 of the pair's tracks on the background
        (two from 140 on), and every layer with enough tracks gets its own PnP pose. Black: no region (the masked
        moving spheres, or clusters under 200 pixels). The legend gives each layer's depth range,
        its track count and its pose status.
    """),
    _code('fig = plot.plot_region_map(clips[1], pair=3, scored=result.clip("moving-masked"))'),
    _md("""
        ## Save and reload

        Results go to CSV (per clip and per pair) or JSON, and come back as rows for the research
        tools (`sgc_jax.calibrate`, `sgc_jax.research.compare`) without re-running any geometry.
    """),
    _code("""\
        import tempfile
        from pathlib import Path

        out = Path(tempfile.mkdtemp())
        result.to_csv(out / "scores.csv", pairs_path=out / "pairs.csv")
        rows = sgc_jax.read_scores(out / "scores.csv")
        [(r["clip_id"], round(r["sgc"], 4)) for r in rows]"""),
    _md("""
        ## In a training or sampling loop

        Clips already in memory or on a device, scored in batches with no file and no host
        round-trip: `sgc_jax.Scorer((B, T, H, W, P))` compiles once for that shape, and
        `scorer(batch)` takes the clip arrays stacked on a leading B axis (NumPy or `jax.Array`;
        `sgc_jax.batch_of(clips)` stacks `Clip`s) and returns `sgc`, the components,
        a status and a `reward` per clip as device arrays, also inside a `jax.jit`
        (docs/semantics.md §9).
    """),
]

SENSITIVITY = [
    _md("""
        # Sensitivity to geometric perturbations (paper Figures 6 and 8b)

        Fix the content, corrupt the geometry by a known amount, and watch the score. Each
        perturbation grows linearly in time (frame 0 untouched, the last frame at full severity):

        - `warp`: a smooth sinusoidal non-rigid deformation of the tracks and frames, depth kept;
        - `squeeze`: a vertical compression of the tracks only;
        - `depth_warp`: one spatial remap of depth, frames and tracks alike.

        `sensitivity_study` perturbs every base clip at every severity, scores everything in
        batched calls and summarises the SGC and each component per kind and severity.
    """),
    _code(SETUP_WITHOUT_NUMPY),
    ENGINE_NOTE,
    _code("""\
        bases = [synth_clip(seed=seed, clip_id=f"scene{seed}", **SCENE) for seed in range(4)]
        study = sgc_jax.sensitivity_study(bases, kinds=sgc_jax.PERTURBATIONS, severities=(0, 0.25, 0.5, 0.75, 1),
                                          chunk_size=CHUNK)
        study.to_pandas(summary=True)"""),
    _md("""
        Spearman ρ between severity and the mean SGC (and each mean component) per kind: 1 means
        the mean rises at every step. `rho_sgc_clips` pools every clip's score.
    """),
    _code('pd.DataFrame(study.correlations()).set_index("kind")'),
    _md("""
        ## SGC vs severity (Figure 6)

        Mean over the base clips, band = ±1 std. As in the paper, dashed reference lines put the
        numbers in context: here the scores of other synthetic clips, two with a static layer that
        drifts (a non-rigid background), one with unmasked moving objects and, for contrast, one
        with the same objects masked.
    """),
    _code("""\
        flawed = sgc_jax.score_batch([
            synth_clip(seed=5, clip_id="layer-drift 0.05", layer_drift=0.05, **SCENE),
            synth_clip(seed=5, clip_id="layer-drift 0.2", layer_drift=0.2, **SCENE),
            synth_clip(seed=4, clip_id="unmasked objects", moving_objects=2, with_mask=False, **SCENE),
            synth_clip(seed=4, clip_id="masked objects", moving_objects=2, **SCENE),
        ], chunk_size=CHUNK)
        references = dict(zip(flawed.clip_ids, flawed.sgc))
        fig = plot.plot_sensitivity(study, references=references)"""),
    _md("""
        ## Component responses (Figure 8b)

        Each perturbation targets one component (`sgc_jax.research.perturb.TARGET_COMPONENT`):
        `warp` the global rotation variance, `squeeze` the local rotation variance, `depth_warp`
        the depth error. None isolates it: in the table above each raises all four pose
        components together (the squeeze raises the global rotation variance about as much as the
        local one, more at severity 1), and `depth_warp` also moves the depth error. The figure
        shows each target component's response.
    """),
    _code("""\
        from sgc_jax.research.perturb import TARGET_COMPONENT

        print(TARGET_COMPONENT)
        fig = plot.plot_component_response(study)"""),
    _md("""
        ## Mask quality (appendix C)

        The same machinery corrupts the moving-object masks: `erode` shrinks them
        (under-segmentation: moving pixels called static), `dilate` grows them
        (over-segmentation). Under-segmentation lets object motion into the background poses and
        the score rises; over-segmentation only removes background support, and the score barely
        moves. `rel_change` is the mean relative change of the SGC vs the clean clips, over the clips
        where it is defined: not where a clean SGC of 0 rose (docs/semantics.md §4).
    """),
    _code("""\
        movers = [synth_clip(seed=seed, clip_id=f"moving{seed}", moving_objects=2, **SCENE) for seed in range(4)]
        masks = sgc_jax.sensitivity_study(movers, kinds=("erode", "dilate"), severities=(0, 0.5, 1), chunk_size=CHUNK)
        masks.to_pandas(summary=True)[["kind", "severity", "sgc", "rel_change", *sgc_jax.COMPONENTS]]"""),
    _code("fig = plot.plot_sensitivity(masks)"),
]

CALIBRATION = [
    _md("""
        # Calibration, weight stability and per-group distributions (paper §3.4, §4.3, Figure 7)

        The SGC is a weighted mean of the five normalised components; μ, σ, the z bounds and the
        weights (absolute PC1 loadings) come from a corpus. This notebook fits them on a synthetic
        corpus of five "models" (groups), compares the weights with the paper's, checks their
        k-fold stability, and shows the per-group score distributions coloured by camera
        dynamics (ECD).
    """),
    _code(SETUP),
    _md("""
        ## A corpus with groups

        Eight clips per group. Every clip gets its own camera speed, so each group spans a range of
        camera dynamics; the groups differ in how they break the rigid-world assumption.
    """),
    _code("""\
        GROUPS = {
            "rigid": {"noise_px": 0.3},
            "noisy-tracks": {"noise_px": 1.5, "outlier_frac": 0.2},
            "mild-drift": {"layer_drift": 0.05},
            "strong-drift": {"layer_drift": 0.2},
            "unmasked-motion": {"moving_objects": 2, "with_mask": False},
        }
        rng = np.random.default_rng(0)
        corpus = []
        for g, (group, flaws) in enumerate(GROUPS.items()):
            for i in range(8):
                motion = dict(rot_deg_per_frame=float(rng.uniform(0.3, 3.0)), trans_per_frame=float(rng.uniform(0.03, 0.3)))
                corpus.append(synth_clip(seed=100 * g + i, clip_id=f"{group}-{i}", group=group, **SCENE, **motion, **flaws))
        len(corpus)"""),
    ENGINE_NOTE,
    _code("""\
        result = sgc_jax.score_batch(corpus, chunk_size=CHUNK)
        scores = result.to_pandas()
        scores.groupby("group")[["sgc", *sgc_jax.COMPONENTS, "ecd"]].mean().sort_values("sgc")"""),
    _md("""
        ## Fit a calibration

        `by="group"` averages the clips of each group first (the paper fitted its weights on
        dataset-group means); `by="clip"` uses every clip as a row. Variances are log1p-transformed,
        standardised and min-max scaled; the weights are the absolute PC1 loadings, summing to 1.
        `floor_band` fits the pose components' excess over their noise floors, as the default
        calibration `sgc-spec-2026` does (docs/semantics.md §5.1, §5.5); without it the fit counts
        the tracker's noise as inconsistency.
    """),
    _code("""\
        paper, default = sgc_jax.Calibration.load("sgc-paper-2026"), sgc_jax.Calibration.load("sgc-spec-2026")
        band = default.floor_band
        by_group = sgc_jax.calibrate(result, by="group", name="synthetic, by group", floor_band=band)
        by_clip = sgc_jax.calibrate(result, by="clip", name="synthetic, by clip", floor_band=band)
        weights = pd.DataFrame({c.name: c.weight for c in (paper, default, by_group, by_clip)})
        weights.loc["PC1 explained variance"] = [float("nan"), float("nan"), by_group.extra["pc1_explained_variance_ratio"],
                                                 by_clip.extra["pc1_explained_variance_ratio"]]
        weights"""),
    _md("""
        ## k-fold stability of the weights (appendix C.1)

        Shuffle the clips into k folds; fit on k-1 folds (grouped, as above), score every clip and
        compare with the full fit. A small fold-to-fold spread of the weights and a Spearman ρ near
        1 mean the ranking does not hinge on which clips were used.
    """),
    _code("""\
        stability = sgc_jax.kfold_stability(result, k=5, by="group", floor_band=band)
        print(stability.table())"""),
    _code("""\
        fig = plot.plot_calibration_weights({"paper (sgc-paper-2026)": paper, "synthetic, by group": by_group},
                                            stability=stability)"""),
    _md("""
        ## Rescore and compare

        A calibration is a function of the stored components, so rescoring re-runs no geometry.
        `sgc_jax.research.compare.group_table` ranks the groups (bootstrap 95% CI of the mean, mean ECD and
        the within-group correlation of SGC with ECD); `agreement_between` says how much the
        ranking of the clips changes between the two calibrations.
    """),
    _code("""\
        from sgc_jax.research.compare import agreement_between, group_table, motion_dependence

        rescored = result.rescore(by_group)
        pd.DataFrame(group_table(rescored.to_records(), n_boot=1000))"""),
    _code("""\
        print("sgc-spec-2026 vs the synthetic calibration, by clip:",
              agreement_between(result.to_records(), rescored.to_records()))
        print("SGC vs camera dynamics:", motion_dependence(rescored.to_records()))"""),
    _md("""
        ## Per-group distributions coloured by camera dynamics (Figure 7)

        Violins with jittered clips, coloured by ECD (the larger of the min-max normalised mean
        camera translation and rotation per pair, over the whole corpus). If a score only measured
        motion, colour would follow height everywhere; look for groups whose slow (dark) clips
        already score high, and for groups that stay low at high ECD.
    """),
    _code("fig = plot.plot_group_violins(rescored)"),
    _md("""
        ## Component correlations (Figure 8a)

        Pearson correlation of the components (variances log1p-transformed, as the score uses them)
        over the clips. The paper reports local and global translation variances as highly
        correlated (r ≈ 0.99) and the others as more distinct.
    """),
    _code("fig = plot.plot_component_correlation(result)"),
    _md("Calibrations are saved and loaded as JSON; the CLI takes them with `--calibration calib.json`."),
    _code("""\
        import tempfile
        from pathlib import Path

        path = by_group.save(Path(tempfile.mkdtemp()) / "calib.json")
        sgc_jax.Calibration.load(path).weight == by_group.weight"""),
]

DIAGNOSTICS = [
    _md("""
        # Diagnostics of one frame pair (paper Figure 4)

        Why does a clip score what it scores? For one pair of frames this notebook shows the local
        pose of every depth layer against the global camera pose as image motion, the depth-warp
        error map, and the reprojection error of each layer's points. `sgc_jax.research.diagnostics`
        recomputes these from the clip and the result that scored it.
    """),
    _code(SETUP),
    _md("""
        Four clips of one scene: rigid; with one static layer that drifts (0.2 scene units per
        frame, unmasked: a non-rigid background); and the rigid clip under two perturbations, a
        squeeze of the tracks and a spatial remap of the depth maps (`depth_warp`).
    """),
    _code("""\
        from sgc_jax.codes import REGION_STATUS_NAMES
        from sgc_jax.research import diagnostics

        rigid = synth_clip(seed=5, clip_id="rigid", **SCENE)
        drift = synth_clip(seed=5, clip_id="layer-drift", layer_drift=0.2, **SCENE)
        squeezed = sgc_jax.perturb_clip(rigid, "squeeze", 1.0)
        bent = sgc_jax.perturb_clip(rigid, "depth_warp", 1.0)
        clips = {c.clip_id: c for c in (rigid, drift, squeezed, bent)}
        result = sgc_jax.score_batch(list(clips.values()), chunk_size=CHUNK)
        result.to_pandas()[["clip_id", "sgc", *sgc_jax.COMPONENTS]]"""),
    ENGINE_NOTE,
    _code("""\
        PAIR = 5  # frames 4 -> 5
        pairs = result.to_pandas(pairs=True)
        pairs[pairs.pair == PAIR][["clip_id", "pair", "reason", *sgc_jax.COMPONENTS, "n_regions", "n_poses", "reproj_error"]]"""),
    _code('fig = plot.plot_region_map(drift, PAIR, scored=result.clip("layer-drift"))'),
    _md("""
        ## Local poses vs the global pose

        At each region's anchor (the centroid of its points, on frame i-1) the blue arrow is the
        image motion the region's own PnP pose predicts, and the red arrow the motion the camera's
        global pose predicts (paper Figure 4). On the rigid clip (the first figure below) the arrows
        agree; where the background is not rigid they part: in the second, the drifting layer's
        regions move on their own, and in the third, under the squeeze, every region's motion bends.
    """),
    _code('fig = plot.plot_pose_arrows(rigid, result.clip("rigid"), PAIR)'),
    _code('fig = plot.plot_pose_arrows(drift, result.clip("layer-drift"), PAIR)'),
    _code('fig = plot.plot_pose_arrows(squeezed, result.clip(squeezed.clip_id), PAIR)'),
    _md("The same numbers as a table: displacement of each anchor in pixels, and the gap between them."),
    _code("""\
        flow = diagnostics.pose_flow(drift, result.clip("layer-drift"), PAIR)
        pd.DataFrame({
            "region": np.arange(1, len(flow.status) + 1), "points": flow.n_points,
            "status": [REGION_STATUS_NAMES[s] for s in flow.status],
            "local dx [px]": flow.local_px[:, 0], "local dy [px]": flow.local_px[:, 1],
            "global dx [px]": flow.global_px[:, 0], "global dy [px]": flow.global_px[:, 1],
            "gap [px]": flow.disagreement_px,
        })"""),
    _md("""
        ## Depth-warp error

        Frame i-1's depth is forward-warped into frame i with the global pose (z-buffer) and
        compared with frame i's depth on static pixels. On a rigid scene only occlusion edges
        remain; the drifting layer leaves bands where its old and new positions disagree.
    """),
    _code("fig = plot.plot_depth_warp_error(drift, PAIR, scale=result.clip('layer-drift').scale)"),
    _code("""\
        warp = diagnostics.depth_warp_error(drift, PAIR, scale=result.clip("layer-drift").scale)
        print(f"mean {warp.mean:.4f} {warp.error_unit} over {warp.compared.sum()} pixels; "
              f"the pair's depth_error: {result.clip('layer-drift').pairs.depth_error[PAIR - 1]:.4f}")"""),
    _md("""
        The `depth_warp` perturbation remaps the depth maps differently in every frame, so the
        warped depth no longer lines up with the next frame's anywhere:
    """),
    _code("fig = plot.plot_depth_warp_error(bent, PAIR, scale=result.clip(bent.clip_id).scale)"),
    _md("""
        ## Reprojection error per region

        Each region's points reprojected with its own local pose (blue) and with the global pose
        (red). A region that fits its own pose but not the camera's is where the world is not
        rigid; a region that fits neither points at tracking or depth errors. The dashed line is
        the RANSAC inlier threshold.
    """),
    _code('fig = plot.plot_region_reprojection(drift, result.clip("layer-drift"), PAIR)'),
    _md("""
        ## Across pairs: does the disagreement persist?

        A tracker's errors are drawn anew for every frame pair; a layer that drifts disagrees with
        the camera in every pair alike. `sgc_jax.research.pose_jitter` compares every two layers'
        relative pose between consecutive pairs against what the noise floors give that change
        (docs/semantics.md §3.10): about 1 when the poses carry only the noise the floors count, or
        a disagreement that persists; above 1 when it changes from pair to pair (errors nearby
        tracks share, depth that flickers, an inconsistency that changes every frame, as the
        perturbations here, which grow with time). Beside each clip: the local rotation variance
        over its floor. (The rigid clip's exact tracks leave its poses apart by float32's rounding
        alone, where both ratios are rounding over rounding.)
    """),
    _code("""\
        from sgc_jax.research.pose_jitter import pose_jitter

        rows = []
        for clip_id in ("layer-drift", squeezed.clip_id, bent.clip_id):
            scored = result.clip(clip_id)
            jitter = pose_jitter(scored.pairs)
            rows.append({"clip_id": clip_id, "sgc": scored.sgc,
                         "local_rot_var / floor": scored.components["local_rot_var"] / scored.floors["local_rot_var_floor"],
                         "jitter, rotations": jitter.rot, "jitter, translations": jitter.trans})
        pd.DataFrame(rows)"""),
    _md("""
        The drifting layer's poses are ten times their floor apart and change between pairs no more
        than the noise says: a persistent disagreement, what an inconsistent world (or a tracker's
        failure that follows one layer) looks like. The jitter is a reading aid, not part of the
        score.
    """),
]

BEST_OF_N = [
    _md("""
        # Best-of-N with the Scorer's reward

        A sampler draws N candidate videos for one prompt and keeps the best. `sgc_jax.Scorer`
        scores a batch of clips already in memory (or on a device) in one set of compiled programs
        and returns, besides the SGC, a **reward** (docs/semantics.md §9.4): higher is better, it
        keeps ranking clips the calibration scores 0, and it pays only for the consistency it
        measured (its `evidence`, §3.11): nothing for what would make a geometric score look
        perfect without a consistent 3D world, such as a still camera, a mask that hides
        everything or no usable tracks, and little for a clip measured on little.

        Here the N = 8 candidates are variants of one synthetic scene: the clean clip, four
        perturbed ones (docs/semantics.md §6.4; severities 0.25 and 0.5) and three decoys.
    """),
    _code(SETUP),
    _code("""\
        import dataclasses

        import jax

        from sgc_jax import batch_of
        from sgc_jax.codes import SCORER_STATUSES

        clean = synth_clip(seed=0, clip_id="clean", **SCENE)
        candidates = [
            clean,
            sgc_jax.perturb_clip(clean, "depth_warp", 0.25),
            sgc_jax.perturb_clip(clean, "depth_warp", 0.5),
            sgc_jax.perturb_clip(clean, "squeeze", 0.25),
            sgc_jax.perturb_clip(clean, "squeeze", 0.5),
            synth_clip(seed=0, clip_id="decoy: still camera", rot_deg_per_frame=0.0, trans_per_frame=0.0, **SCENE),
            dataclasses.replace(clean, clip_id="decoy: all masked", static_mask=np.zeros_like(clean.static_mask)),
            dataclasses.replace(clean, clip_id="decoy: no tracks", track_vis=np.zeros_like(clean.track_vis)),
        ]
        labels = [c.clip_id for c in candidates]"""),
    _md("""
        ## Score the candidates

        A Scorer is built for one shape (B, T, H, W, P) and compiled once (about a minute on a CPU
        the first time; later sessions load it from the on-disk cache). Here B = 4, the test
        suite's shape, and the 8 candidates go in two calls; `batch_of` stacks `Clip`s into the
        dict of arrays a call takes. Each call returns a dict of `jax.Array`s (B,).
    """),
    _code("""\
        T, H, W, P = SCENE["n_frames"], SCENE["height"], SCENE["width"], SCENE["n_tracks"]
        scorer = sgc_jax.Scorer((4, T, H, W, P))
        calls = [scorer(batch_of(candidates[i:i + 4])) for i in (0, 4)]
        out = {name: np.concatenate([np.asarray(call[name]) for call in calls]) for name in calls[0]}
        table = pd.DataFrame({"candidate": labels, "status": [SCORER_STATUSES[s] for s in out["status"]],
                              **{k: out[k] for k in ("sgc", "sgc_unclipped", "camera_motion", "evidence",
                                                     "reward")}})
        table.sort_values("reward", ascending=False)"""),
    _md("""
        The clean clip earns the highest reward and is the one best-of-N keeps; the perturbed
        clips follow in the order of their scores. Two decoys tie with the clean clip at `sgc` = 0:
        the still camera, whose local poses all agree because nothing moves, and the track-less
        clip, scored on its depth error alone. Neither earns anything: the reward is the logistic
        of the score (with the depth error counted again above its zero, since without parallax
        it alone sees a depth inconsistency) times the clip's `evidence`, the share of its pairs'
        geometry that was measured, and a pair counts in proportion to its camera's motion
        against the full-motion level (1 % of D or 0.5° per pair): the still camera's evidence
        is 0 and its status `static_camera`; the track-less and all-masked clips are measured on
        nothing (`no_tracks`, `no_static`). `sgc_unclipped` drops the calibration's floor at 0
        of each normalised component, so clips whose depth error is below the clean
        clips' 90th percentile still rank among themselves; a pose component within its noise band
        counts 0 in both (below the noise there is nothing to rank).
    """),
    _code("""\
        best = labels[int(np.argmax(out["reward"]))]
        print(f"best of {len(candidates)}: {best}")"""),
    _code("fig = plot.plot_rewards(labels, out)"),
    _md("""
        ## Time per batch

        A warm call on this machine (the figure varies from run to run and machine to machine;
        bench/reward.py measures standard clips and batch sizes). On a CPU the Scorer runs a batch
        in two lanes of clips at once; on an accelerator in one vectorized program
        (docs/semantics.md §9.3).
    """),
    _timing("""\
        import time

        batch = batch_of(candidates[:4])
        seconds = []
        for _ in range(5):
            start = time.perf_counter()
            jax.block_until_ready(scorer(batch))
            seconds.append(time.perf_counter() - start)
        per_batch = float(np.median(seconds))
        print(f"{1000 * per_batch:.0f} ms per batch of 4 on {jax.devices()[0].device_kind}: {4 / per_batch:.1f} clips/s")"""),
]

GRADIENTS = [
    _md("""
        # Gradients of SGC

        `sgc_jax.Scorer(shape, differentiable=True)` also returns `sgc_smooth`, a form of the score
        that `jax.grad` differentiates with respect to the clip's depth, tracks, cameras and
        intrinsics (docs/semantics.md §10). The forward pass makes every discrete choice (regions,
        RANSAC's inliers, the warp's z-buffer) and those are held fixed; local poses are
        differentiated at their least-squares optimum; the calibration's floor at 0 becomes a
        smooth bound, so a clip that scores 0 still has a gradient (from its depth error, and from
        each pose component above its noise band). Lower is better.

        Two uses: repairing a clip's depth by descending the score, and finding the tracks that
        break a clip's consistency.
    """),
    _code(SETUP),
    _code("""\
        import dataclasses

        import jax
        import jax.numpy as jnp

        from sgc_jax import batch_of

        T, H, W, P = SCENE["n_frames"], SCENE["height"], SCENE["width"], SCENE["n_tracks"]
        scorer = sgc_jax.Scorer((2, T, H, W, P), differentiable=True)  # two clips per batch"""),
    _md("""
        ## Repairing a corrupted depth

        A consistent scene (0.5 px of track noise) whose depth alone is corrupted: each frame's
        depth multiplied by its own smooth field of up to ±10 % (a random quadratic surface over
        the image). Tracks and cameras are untouched, so the depth no longer agrees with them.
        The batch holds the clean clip beside the corrupted one.
    """),
    _code("""\
        clean = synth_clip(seed=0, clip_id="clean", noise_px=0.5, **SCENE)
        rng = np.random.default_rng(0)
        yy, xx = np.mgrid[0:H, 0:W]
        xn, yn = 2 * xx / (W - 1) - 1, 2 * yy / (H - 1) - 1
        basis = np.stack([np.ones_like(xn), xn, yn, xn * yn, xn**2, yn**2]).astype(np.float32)  # (6, H, W)
        field = np.einsum("tk,khw->thw", rng.normal(0, 1, (T, 6)), basis)
        field = 0.1 * field / np.abs(field).max(axis=(1, 2), keepdims=True)
        corrupted = dataclasses.replace(clean, clip_id="corrupted", depth=(clean.depth * (1 + field)).astype(np.float32))
        batch = batch_of([clean, corrupted])
        clean_sgc, corrupted_sgc = np.asarray(scorer(batch)["sgc"])
        print(f"clean: sgc {clean_sgc:.2f}; corrupted: sgc {corrupted_sgc:.2f}")"""),
    _md("""
        Gradient descent on `sgc_smooth` with respect to the depth alone, through a correction of
        the same family: each frame's depth times exp of a quadratic surface, its 6 coefficients
        per frame the parameters (Adam, step 0.01). Each step runs the forward pass anew, so its
        choices follow the depth. The error to the true depth is the mean |d − d_true| / d_true over
        valid pixels after matching each frame's median scale: the depth check reads each pair up to
        its depth scale (docs/semantics.md §3.6 step 7), so the descent leaves each frame's scale where
        it drifts.
    """),
    _cpu_rounded("""\
        valid = clean.depth > 0

        def repaired(theta):  # the batch's depth, the corrupted clip's corrected
            correction = jnp.exp(jnp.einsum("tk,khw->thw", theta, basis))
            return jnp.asarray(batch["depth"]).at[1].multiply(correction)

        def error_to_truth(depth):  # each frame's depth matched to the truth at its median scale
            d, truth = np.asarray(depth)[1], clean.depth
            scale = np.array([np.median(d[t][valid[t]] / truth[t][valid[t]]) for t in range(T)])[:, None, None]
            return 100 * np.mean((np.abs(d / scale - truth) / truth)[valid])

        def gradient(clips):  # d sum(sgc_smooth) / d every float input; clip b's slice is d sgc_smooth[b]
            floats = {name: clips[name] for name in ("depth", "track_prev", "track_curr", "R_wc", "t_wc", "K")}
            return jax.grad(lambda f: scorer({**clips, **f})["sgc_smooth"].sum())(floats)

        theta = jnp.zeros((T, 6), jnp.float32)
        moment, second = jnp.zeros_like(theta), jnp.zeros_like(theta)
        history = []
        for step in range(30):
            depth, pullback = jax.vjp(repaired, theta)
            history.append((step, float(scorer({**batch, "depth": depth})["sgc"][1]), error_to_truth(depth)))
            (grad,) = pullback(gradient({**batch, "depth": depth})["depth"])
            moment, second = 0.9 * moment + 0.1 * grad, 0.999 * second + 0.001 * grad**2
            theta = theta - 0.01 * (moment / (1 - 0.9 ** (step + 1))) / (jnp.sqrt(second / (1 - 0.999 ** (step + 1))) + 1e-8)
        descent = pd.DataFrame(history, columns=["step", "sgc", "depth error to truth (%)"])
        descent.iloc[[0, -1]].round(1)  # one decimal: a descent's last digits depend on the CPU's rounding"""),
    _code("""\
        fig = plot.plot_descent(descent["step"], descent["sgc"], descent["depth error to truth (%)"], reference_sgc=clean_sgc)"""),
    _md("""
        The score falls towards the clean clip's and the depth towards the truth, from the score's
        gradient alone: nothing in the descent sees the true depth. The error falls from about 2 % to
        under 1 % in 30 steps, not to 0:
        exp of a quadratic surface is not exactly 1 + a quadratic surface, and what the tracks
        and cameras constrain is where the tracks are.

        ## Which tracks break consistency

        The same scene with a sphere moving on its own and no motion mask: its tracks describe a
        motion the camera's does not explain. The gradient of `sgc_smooth` with respect to
        `track_curr`, per track, is largest on them.
    """),
    _code("""\
        spec = dict(SCENE, moving_objects=1)
        masked = synth_clip(seed=1, **spec)  # the same scene with its mask: which pixels move
        unmasked = synth_clip(seed=1, with_mask=False, **spec)
        moving = batch_of([unmasked, masked])
        grad = gradient(moving)["track_curr"]
        norm = np.linalg.norm(np.asarray(grad)[0], axis=-1)  # (T-1, P)
        col = np.clip(unmasked.track_prev[..., 0].astype(int), 0, W - 1)
        row = np.clip(unmasked.track_prev[..., 1].astype(int), 0, H - 1)
        on_object = ~masked.static_mask[:-1][np.arange(T - 1)[:, None], row, col] & unmasked.track_vis
        static = ~on_object & unmasked.track_vis
        print(f"sgc {float(scorer(moving)['sgc'][0]):.2f}; mean gradient norm per track: "
              f"moving sphere {norm[on_object].mean():.2e}, static scene {norm[static].mean():.2e} "
              f"({norm[on_object].mean() / norm[static].mean():.0f}x)")
        ratio = [norm[p][on_object[p]].mean() / norm[p][static[p]].mean() if on_object[p].any() else 0.0
                 for p in range(T - 1)]
        pair = int(np.argmax(ratio)) + 1  # pair i = frames i-1 -> i, row i-1
        # which pairs stand out (> 10x) is stable; the small ratios follow RANSAC's choices, which
        # another CPU's rounding may change (1.8x on an Intel box, 2.0x on an AMD one): whole x only
        strong = [p + 1 for p in range(T - 1) if ratio[p] > 10]
        print(f"pairs where they carry > 10x the static gradient: {strong} "
              f"({', '.join(f'{ratio[i - 1]:.0f}x' for i in strong)}); elsewhere at most "
              f"{max((r for p, r in enumerate(ratio) if p + 1 not in strong), default=0.0):.0f}x; shown: pair {pair}")"""),
    _md("""
        Per pair the picture is sharper than the mean: where the sphere's tracks form a region of
        their own, its pose disagrees with the others and its tracks carry tens of times the
        gradient of the static ones; where they share a region with static points, RANSAC leaves
        them out of that region's pose as outliers, a choice the gradient holds fixed, so no
        gradient reaches them there (ratios below 1). The tracks of the pair where the sphere's
        stand out most, over the depth of its second frame (the sphere is the disc nearer than
        the wall behind it):
    """),
    _code("fig = plot.plot_track_gradients(unmasked, pair, norm)"),
]

NOTEBOOKS = {
    "01_quickstart": QUICKSTART,
    "02_sensitivity": SENSITIVITY,
    "03_calibration": CALIBRATION,
    "04_diagnostics": DIAGNOSTICS,
    "05_best_of_n": BEST_OF_N,
    "06_gradients": GRADIENTS,
}


def build(name: str):
    """The notebook ``name`` without outputs (deterministic cell ids, so rebuilds diff cleanly)."""
    import nbformat

    nb = nbformat.v4.new_notebook()
    nb.metadata.update({
        "kernelspec": {"display_name": "Python 3", "language": "python", "name": "python3"},
        "language_info": {"name": "python"},
    })
    for i, (kind, source) in enumerate(NOTEBOOKS[name]):
        make = nbformat.v4.new_markdown_cell if kind == "markdown" else nbformat.v4.new_code_cell
        cell = make(source, id=f"{name[:2]}-{i:02d}")
        if kind in ("timing", "cpu-rounding"):
            cell.metadata["tags"] = [kind]
        nb.cells.append(cell)
    return nb


def execute(nb, *, cwd: Path = HERE, timeout: int = TIMEOUT_S):
    """Run every cell in a fresh ``python3`` kernel; raises ``CellExecutionError`` on an error. The
    stored notebooks show results only: no compile lines."""
    from nbclient import NotebookClient

    client = NotebookClient(nb, timeout=timeout, kernel_name="python3", record_timing=False,
                            resources={"metadata": {"path": str(cwd)}})
    before = os.environ.get("SGC_JAX_COMPILE_MESSAGES")
    os.environ["SGC_JAX_COMPILE_MESSAGES"] = "off"  # the kernel inherits it
    try:
        client.execute()
    finally:
        if before is None:
            del os.environ["SGC_JAX_COMPILE_MESSAGES"]
        else:
            os.environ["SGC_JAX_COMPILE_MESSAGES"] = before
    return nb


def main(argv: list[str]) -> int:
    import nbformat

    names = argv or list(NOTEBOOKS)
    unknown = [n for n in names if n not in NOTEBOOKS]
    if unknown:
        print(f"unknown notebook(s) {unknown}; notebooks: {list(NOTEBOOKS)}", file=sys.stderr)
        return 2
    for name in names:
        start = time.perf_counter()
        nb = execute(build(name))
        nbformat.write(nb, HERE / f"{name}.ipynb")
        print(f"{name}.ipynb: executed in {time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
