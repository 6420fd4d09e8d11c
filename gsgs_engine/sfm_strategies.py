"""Sparse-set camera solving: the mapping strategies gsgs_engine.sfm tries, cheapest first,
and the rule that keeps the best result.

COLMAP's incremental mapper is tuned for dozens of photos. With 3-8 photos its initial pair
needs a wide baseline, so adjacent hand-held frames register nothing; the global mapper
(GLOMAP, `pycolmap.global_mapping`) solves rotations and positions for all photos at once and
needs no initial pair. The strategies, in order of cost:

  incremental   incremental mapping with sparse-set thresholds; for a small set the initial
                pair's minimum triangulation angle steps down (4, 2, 1, 0.5 degrees) until
                every photo registers
  global        global mapping; for a small set two-view tracks count (3 photos rarely share
                many three-view tracks)
  stragglers    the best model so far, continued by the incremental mapper with relaxed
                absolute-pose thresholds, for the photos it left out

The best result has the most registered photos, then the lowest mean reprojection error,
then the most points. Sets up to SMALL_SET photos run every strategy; larger sets stop at the
first that registers every photo. Everything here that touches pycolmap runs in the SfM child
process and receives the module as an argument (see gsgs_engine.sfm's docstring: pycolmap must
never load in the parent).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

STRATEGIES = ("incremental", "global", "stragglers")
INCREMENTAL_ANGLES = (4.0, 2.0, 1.0, 0.5)  # init_min_tri_angle ladder (degrees) for small sets
SEED = 0
# A "model" with fewer points than this places cameras without structure (the incremental
# mapper can register 3 photos and then filter every point away); it is not a solution.
MIN_POINTS = 20

DESCRIPTIONS = {
    "incremental": "incremental mapping",
    "global": "global mapping (GLOMAP)",
    "stragglers": "straggler registration with relaxed absolute-pose thresholds",
}


@dataclass
class Attempt:
    """One strategy's outcome; `model_dir` holds its largest model (COLMAP binary)."""

    strategy: str  # e.g. "incremental 2deg", "global", "global + stragglers"
    registered: int
    num_points: int
    mean_reprojection_error: float | None
    seconds: float
    model_dir: str = ""
    note: str = ""  # why it produced nothing, or was skipped

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("model_dir")
        return d


def describe(label: str) -> str:
    """'global + stragglers' -> 'global mapping (GLOMAP) + straggler registration ...'."""
    parts = []
    for part in label.split(" + "):
        kind, _, angle = part.partition(" ")
        text = DESCRIPTIONS.get(kind, part)
        parts.append(f"{text} (initial pair at least {angle.removesuffix('deg')} degrees apart)" if angle else text)
    return " + ".join(parts)


# ---------------------------------------------------------------------------------------
# Choosing (plain Python, no pycolmap)
# ---------------------------------------------------------------------------------------
def rank_key(a: Attempt) -> tuple:
    """Larger is better: most photos registered, then lowest reprojection error, then most points."""
    error = a.mean_reprojection_error if a.mean_reprojection_error is not None else float("inf")
    return (a.registered, -round(error, 4), a.num_points)


def pick_best(attempts: list[Attempt]) -> Attempt | None:
    """The best attempt with a model (first one wins a tie: it was the cheaper), or None."""
    best = None
    for a in attempts:
        if a.registered < 2 or a.num_points < MIN_POINTS:
            continue
        if best is None or rank_key(a) > rank_key(best):
            best = a
    return best


def why_best(best: Attempt, attempts: list[Attempt], total: int) -> str:
    """One sentence: why this attempt won against the others."""
    others = [a for a in attempts if a is not best and a.registered >= 2 and a.num_points >= MIN_POINTS]
    if not others:
        return f"the only strategy that built a model ({best.registered}/{total} photos)"
    fewer = [a for a in others if a.registered < best.registered]
    tied = [a for a in others if a.registered == best.registered]
    parts = [f"registered {best.registered}/{total} photos"]
    if fewer and not tied:
        parts.append("more than any other strategy")
    if tied:
        err = best.mean_reprojection_error or 0.0
        worse = min(tied, key=lambda a: a.mean_reprojection_error or 0.0)
        if round(err, 4) < round(worse.mean_reprojection_error or 0.0, 4):
            parts.append(f"with the lowest reprojection error ({err:.3f} px; next best {worse.strategy} "
                         f"{worse.mean_reprojection_error:.3f} px)")
        else:
            parts.append(f"as accurately as {worse.strategy} and with more points "
                         f"({best.num_points} vs {worse.num_points})" if best.num_points > worse.num_points
                         else f"tied with {worse.strategy}, and it ran first")
    return ", ".join(parts)


# ---------------------------------------------------------------------------------------
# Strategies (child process only)
# ---------------------------------------------------------------------------------------
def solve(pycolmap, db_path: Path, photo_dir: Path, work: Path, num_images: int, small: bool, min_inliers: int,
          emit: Callable[[str, str], None], strategies=STRATEGIES,
          fix_focal: bool = False) -> tuple[Attempt | None, list[Attempt]]:
    """Run the strategies named in `strategies` (a subset of STRATEGIES, run in STRATEGIES order)
    and return (best attempt or None, every attempt). Models land in work/<strategy>/.
    `fix_focal`: keep the cameras' focal length (from EXIF) instead of refining it."""
    unknown = set(strategies) - set(STRATEGIES)
    if unknown:
        raise ValueError(f"unknown SfM strategies {sorted(unknown)}; choose from {STRATEGIES}")
    attempts: list[Attempt] = []

    def done() -> bool:
        best = pick_best(attempts)
        return best is not None and best.registered == num_images

    if "incremental" in strategies:
        angles = INCREMENTAL_ANGLES if small else (None,)
        for angle in angles:
            label = "incremental" if angle is None else f"incremental {angle:g}deg"
            emit("mapping", f"{label}: {DESCRIPTIONS['incremental']}"
                 + ("" if angle is None else f", initial pair at least {angle:g} degrees apart"))
            attempt = _run(pycolmap, label, work, lambda out, a=angle: _incremental(
                pycolmap, db_path, photo_dir, out, small, min_inliers, a, fix_focal=fix_focal))
            attempts.append(attempt)
            if attempt.registered == num_images:
                break  # a smaller angle only ever helps to register more
    if "global" in strategies and (small or not done()):
        if not hasattr(pycolmap, "global_mapping"):
            attempts.append(Attempt("global", 0, 0, None, 0.0, note=f"pycolmap {pycolmap.__version__} has no "
                                    "global_mapping; install pycolmap 4.2 or newer"))
        else:
            emit("mapping", f"global: {DESCRIPTIONS['global']}")
            attempts.append(_run(pycolmap, "global", work, lambda out: _global(
                pycolmap, db_path, photo_dir, out, small, min_inliers, fix_focal)))
    best = pick_best(attempts)
    if "stragglers" in strategies and best is not None and best.registered < num_images:
        missing = num_images - best.registered
        emit("mapping", f"stragglers: registering {missing} photo(s) left out by {best.strategy}")
        attempts.append(_run(pycolmap, f"{best.strategy} + stragglers", work, lambda out: _incremental(
            pycolmap, db_path, photo_dir, out, small, min_inliers, INCREMENTAL_ANGLES[-1] if small else None,
            input_path=Path(best.model_dir), relaxed=True, fix_focal=fix_focal)))
        best = pick_best(attempts)
    return best, attempts


def _run(pycolmap, label: str, work: Path, mapper) -> Attempt:
    out = work / label.replace(" + ", "+").replace(" ", "_")
    out.mkdir(parents=True, exist_ok=True)
    pycolmap.set_random_seed(SEED)
    started = time.time()
    models = mapper(out)
    seconds = round(time.time() - started, 2)
    if not models:
        return Attempt(label, 0, 0, None, seconds, note="no model")
    rec = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    if rec.num_points3D() < MIN_POINTS:
        return Attempt(label, int(rec.num_reg_images()), int(rec.num_points3D()), None, seconds,
                       note=f"degenerate: {rec.num_points3D()} points for {rec.num_reg_images()} photos")
    best_dir = out / "best"
    best_dir.mkdir(exist_ok=True)
    rec.write(best_dir)
    error = rec.compute_mean_reprojection_error() if rec.num_points3D() else None
    return Attempt(label, int(rec.num_reg_images()), int(rec.num_points3D()),
                   None if error is None else float(error), seconds, model_dir=str(best_dir))


def incremental_options(pycolmap, small: bool, min_inliers: int, angle: float | None = None, relaxed: bool = False,
                        fix_focal: bool = False):
    """COLMAP's defaults assume dozens of photos; with 2-10 the initial pair must be allowed
    fewer inliers and a smaller baseline, and two-view tracks are most of the structure.
    `relaxed`: stragglers may register from fewer, less consistent 2D-3D matches."""
    options = pycolmap.IncrementalPipelineOptions()
    if small:
        options.min_num_matches = min_inliers
        options.mapper.init_min_num_inliers = 50
        options.mapper.init_min_tri_angle = 4.0 if angle is None else float(angle)
        options.mapper.abs_pose_min_num_inliers = 15
        options.mapper.abs_pose_min_inlier_ratio = 0.15
        options.triangulation.ignore_two_view_tracks = False
        options.min_model_size = 2
    if relaxed:
        options.mapper.abs_pose_min_num_inliers = 8
        options.mapper.abs_pose_min_inlier_ratio = 0.05
        options.mapper.abs_pose_max_error = 16.0
        options.mapper.max_reg_trials = 10
        options.structure_less_registration_fallback = True
    if fix_focal:
        options.ba_refine_focal_length = False
        options.mapper.abs_pose_refine_focal_length = False
    _seed_incremental(options, small)
    return options


def _seed_incremental(options, small: bool) -> None:
    # Same photos, same cameras: every RANSAC and the mapper draw from a fixed seed, and a
    # small set maps on one thread (bundle adjustment sums in a fixed order).
    options.random_seed = SEED
    options.mapper.random_seed = SEED
    options.triangulation.random_seed = SEED
    if small:
        options.num_threads = 1
        options.mapper.num_threads = 1


def _incremental(pycolmap, db_path, photo_dir, out, small, min_inliers, angle, input_path: Path | None = None,
                 relaxed: bool = False, fix_focal: bool = False):
    options = incremental_options(pycolmap, small, min_inliers, angle, relaxed, fix_focal)
    return pycolmap.incremental_mapping(db_path, photo_dir, out, options=options,
                                        input_path=str(input_path) if input_path else "")


def global_options(pycolmap, small: bool, min_inliers: int, fix_focal: bool = False):
    options = pycolmap.GlobalPipelineOptions()
    m = options.mapper
    if fix_focal:
        m.bundle_adjustment.refine_focal_length = False
    if small:
        options.min_num_matches = min_inliers
        options.min_model_size = 2
        # 3-8 photos share few tracks seen by three of them; two-view tracks carry the model.
        m.track_min_num_views_per_track = 2
        m.global_positioning.min_num_view_per_track = 2
        m.bundle_adjustment.min_track_length = 2
        m.retriangulation.ignore_two_view_tracks = False
        options.num_threads = 1
        m.num_threads = 1
        m.bundle_adjustment.ceres.solver_options.num_threads = 1
    options.random_seed = SEED
    m.random_seed = SEED
    m.rotation_averaging.random_seed = SEED
    m.global_positioning.random_seed = SEED
    m.retriangulation.random_seed = SEED
    return options


def _global(pycolmap, db_path, photo_dir, out, small, min_inliers, fix_focal=False):
    return pycolmap.global_mapping(db_path, photo_dir, out,
                                   options=global_options(pycolmap, small, min_inliers, fix_focal))
