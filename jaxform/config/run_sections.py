"""The config sections of how a run goes and what it writes: [time], [solver], [output],
and the commands beyond one run, [design] and [study].  This module imports no JAX."""

from __future__ import annotations

from dataclasses import dataclass

from jaxform.config.schema import key, section
from jaxform.design.requirements import GROUPS, OBJECTIVES


@section("time")
@dataclass(frozen=True, kw_only=True)
class TimeConfig:
    """[time]: the load steps."""

    dt_s: float = key(low=0.0, low_open=True, doc="largest time step (s): steps adapt below it")
    dt_growth: float = key(
        1.5,
        low=1.0,
        high=4.0,
        doc="after an easy step (no cutback, few Newton iterations) the next step grows by this "
        "factor, up to time.dt_s (1: never grows back)",
    )
    alpha: float = key(
        0.5, low=0.0, high=1.0, doc="generalized mid-point parameter of the strain increment"
    )
    first_step_probe: float = key(
        0.25,
        low=0.0,
        high=1.0,
        high_open=True,
        doc="a step from rest (a run's or an operation's first: t = 0, every rate 0) first solves "
        "this fraction of itself, and the probe's rate is the predictor of the step, which "
        "converges to the same root (0: no probe; see jaxform/stepping.py attempt_step)",
    )


@section("solver")
@dataclass(frozen=True, kw_only=True)
class SolverConfig:
    """[solver]: Newton, linear solver, chunks, memory, compilation cache."""

    max_newton_iterations: int = key(
        25,
        low=1,
        high=1000,
        doc="Newton iterations per step before a cutback (modified Newton: those with a new "
        "Jacobian; up to 3x as many more with a kept factorization)",
    )
    rtol: float = key(
        1e-10,
        low=0.0,
        high=1.0,
        low_open=True,
        high_open=True,
        doc="relative residual tolerance of Newton",
    )
    max_cutbacks: int = key(6, low=0, high=30, doc="times a failed step may be halved")
    smallest_step_continuations: int = key(
        3,
        low=0,
        high=20,
        doc="at the smallest step (after max_cutbacks halvings), times a Newton solve that has "
        "not converged goes on from its last iterate (max_newton_iterations more each) before "
        "the run stops; runs that never fail at the smallest step are unchanged",
    )
    line_search: bool = key(True, doc="backtracking line search in Newton")
    max_quality_drop: float = key(
        0.0,
        low=0.0,
        high=2.0,
        doc="the most an element corner's quality (1 square, 0 degenerate) may fall in one "
        "converged step before the step is cut back where a smaller step is left (0: no "
        "limit; 0.25 keeps a large step off a spurious root of the contact and friction "
        "conditions, a corner rolled over at once; off by default: it changes the steps of "
        "scenes that need none, see docs/theory.md)",
    )
    stall_iterations: int = key(
        0,
        low=0,
        high=1000,
        doc="a Newton solve whose least residual has not fallen below solver.stall_ratio x the "
        "least of this many iterations earlier stops and the step is cut back, where a "
        "smaller step is left (0: never; a step that would fail after max_newton_iterations "
        "fails sooner; see jaxform/solver.py stalled)",
    )
    stall_ratio: float = key(
        0.9,
        low=0.0,
        high=1.0,
        low_open=True,
        high_open=True,
        doc="the fall of the least Newton residual over solver.stall_iterations iterations "
        "below which a solve has stalled",
    )
    linear: str = key(
        "auto",
        choices=("auto", "dense", "sparse", "pardiso", "jax-sparse"),
        doc="linear solver backend (auto: on CPU dense LU below 100 unknowns, klujax sparse LU "
        "above, Intel MKL PARDISO from 20 000 where installed (x86-64); on a GPU dense LU "
        "below 20 000, jax-sparse (cuSolver) above; see jaxform/linear.py)",
    )
    newton: str = key(
        "auto",
        choices=("auto", "newton", "modified"),
        doc="newton: a new Jacobian and factorization every iteration; modified: one "
        "factorization kept across iterations and steps, refreshed when a step contracts the "
        "residual by less than 2x (needs linear = dense, sparse or pardiso); auto: modified on the "
        "sparse backend, where the scene remeshes only from MODIFIED_MIN_UNKNOWNS unknowns "
        "(newton below; see jaxform/solver.py)",
    )
    anderson_depth: int = key(
        3,
        low=0,
        high=10,
        doc="modified Newton: each step with a kept factorization is mixed with up to this many "
        "earlier ones (Anderson acceleration; fewer iterations for the same root; 0: plain "
        "steps; see jaxform/solver.py)",
    )
    adjoint_memory_mb: float = key(
        4096.0,
        low=0.0,
        doc="memory (MB) a gradient run may hold in forward factorizations kept for its reverse "
        "pass, which then refines each step's adjoint solve with the kept factors instead of "
        "factoring again; the last steps that fit are kept, the others factor in the reverse "
        "pass (0: none kept; ~69 MB a step at 100 x 100 with klujax; see "
        "jaxform/gradients.py)",
    )
    chunk_steps: int = key(
        8,
        low=1,
        high=10000,
        doc="load steps per compiled chunk (progress is reported between chunks)",
    )
    chunk_output_mb: float = key(
        64.0,
        low=0.01,
        high=1e6,
        doc="the most a chunk's per-step output fields (unknowns, stresses, strains, damage) "
        "may take together, MB: a chunk takes fewer than solver.chunk_steps steps on a mesh "
        "whose fields take more (200 x 200 seed scene: 18.5 MB a step, 3 steps a chunk; "
        "up to 100 x 100 the 8 steps stay)",
    )
    compilation_cache_dir: str = key(
        "auto",
        doc="where compiled programs are kept for the next run: a directory, 'off', or 'auto' "
        "(the environment variable JAXFORM_CACHE_DIR, else ~/.cache/jaxform; see "
        "jaxform/cache.py)",
    )


@section("output")
@dataclass(frozen=True, kw_only=True)
class OutputConfig:
    """[output]: what a run writes."""

    fields: bool = key(True, doc="write ParaView fields (VTU series)")
    plots: bool = key(True, doc="write PNG plots")
    profile_strokes_mm: tuple[float, ...] = key(
        [],
        doc="ram strokes (mm) at which the contact pressure/slip profile is plotted ([] = "
        "25/50/75/100 %)",
    )
    animation: bool = key(
        False,
        doc="write animation.gif: the section through the run (deformed mesh, equivalent "
        "plastic strain, the dies) from the stored fields; needs output.plots",
    )
    animation_frames: int = key(
        40,
        low=2,
        high=1000,
        doc="the animation's frames at most (history rows evenly spread, first and last kept)",
    )
    lap_angle_deg: float = key(
        10.0,
        low=0.0,
        high=90.0,
        doc="report a lap where a wedge of the free surface (history wedge_angle_deg: the "
        "surface folded onto itself) and a pocket where air between the material and a die "
        "(pocket_angle_deg = atan(gap / half its length)) stays below this to the end (deg; "
        "0 = never)",
    )
    damage_critical: float = key(
        0.0,
        low=0.0,
        high=100.0,
        doc="critical value of output.damage_criterion: elements at or above it are flagged "
        "(cell field damage_flag, damage.png; history damage_flagged) (0 = no flag)",
    )
    damage_criterion: str = key(
        "cl",
        choices=("cl", "brozzo", "ayada"),
        doc="the damage integral output.damage_critical applies to: normalized "
        "Cockcroft-Latham, Brozzo or Ayada (docs: outputs)",
    )
    flow_line_spacing_mm: float = key(
        0.0,
        low=0.0,
        high=1e4,
        doc="follow material lines of the initial section at this spacing (mm) through the "
        "run and its remeshes: flow_lines.png, fields/flow_lines_*.vtu (0 = none)",
    )


@section("design")
@dataclass(frozen=True, kw_only=True)
class DesignConfig:
    """[design]: design problems (jaxform design and taylor-test)."""

    objective: str = key(
        "forging_work",
        choices=tuple(OBJECTIVES),
        doc="design objective (jaxform design / taylor-test), a function of the run: force "
        "integral over stroke (N mm), peak ram force (N), mean squared deviation of the final"
        " side from straight (mm^2), of chosen nodes from target positions (mm^2), "
        "force-stroke misfit against a target curve, variance of eqps, 1 - die fill, mean "
        "squared misfit of the mean temperature history against a target (K^2), a smooth "
        "maximum of output.damage_criterion's damage at the end (-) or of the die wear "
        "depth (mm; needs wear.on) (design.smooth_max_p), the flash volume, press capacity "
        "and lap penalties, a weighted sum, the mean temperature at the end (K)",
    )
    smooth_max_p: float = key(
        8.0,
        low=1.0,
        high=64.0,
        doc="exponent p of the power mean (mean of x^p)^(1/p) that objectives max_damage "
        "and wear_depth take as a smooth maximum: between N^(-1/p) max and max",
    )
    max_temperature_K: float = key(
        0.0,
        low=0.0,
        high=5000.0,
        doc="a limit on the hottest node (K; coupled runs): the objective gains "
        "design.temperature_penalty x sum over steps of max(0, T_max - limit)^2 (0: none)",
    )
    temperature_penalty: float = key(
        1.0,
        low=0.0,
        low_open=True,
        doc="weight of the temperature-limit penalty (objective units per K^2)",
    )
    variables: tuple[str, ...] = key(
        ["material"],
        choices=tuple(GROUPS),
        doc="design variable groups jaxform design optimizes",
    )
    operation: str = key(
        "",
        doc="a process ([[process.operation]]): the operation (its name) whose inputs the "
        "operation groups of design.variables vary (die, friction, speed, thermal, dwell; "
        "'' = the first forming operation; jaxform taylor-test --groups may name one per "
        "group, e.g. finisher.friction)",
    )
    operation_variables: tuple[str, ...] = key(
        [],
        doc="a process: design groups of named operations, '<operation>.<group>' (group: "
        "die, friction, speed, thermal, dwell; e.g. blocker.die, finisher.friction), "
        "besides design.variables (set that to [] for these alone)",
    )
    objective_operation: str = key(
        "",
        doc="a process: the operation whose run design.objective reads (peak_force, "
        "forging_work, press_capacity, flash_volume, die_fill, lap, mean_temperature; '' = "
        "the last forming one)",
    )
    material_params: tuple[str, ...] = key(
        [],
        doc="material parameters of the 'material' group (names of the law's parameters); "
        "empty: the law's own choice (anand: s0_MPa, h0_MPa, s_hat_MPa; j2: sigma_y0_MPa, "
        "H_MPa; elastic: G_MPa, K_MPa)",
    )
    material_start_factor: float = key(
        1.0,
        low=0.0,
        low_open=True,
        doc="the design starts from the material parameters times this (e.g. 0.7 to identify from"
        " 30 % off)",
    )
    thermal_params: tuple[str, ...] = key(
        [],
        doc="inputs of the 'thermal' group: any of billet_temperature_K, die_temperature_K, "
        "htc_die_W_m2K, taylor_quinney (thermal.* keys); empty: all four",
    )
    preform_modes: int = key(3, low=1, high=20, doc="cosine modes of the preform profile")
    preform_amplitude_max: float = key(
        0.2,
        low=0.0,
        high=0.9,
        low_open=True,
        doc="bound on each preform mode amplitude (fraction of the radius)",
    )
    node_offset_max_mm: float = key(
        0.1,
        low=0.0,
        low_open=True,
        doc="bound on each initial node coordinate's offset of the 'nodes' group (mm)",
    )
    die_points: tuple[float, ...] = key(
        [], doc="indices of die.profile_mm points whose z is a design variable ([] = all)"
    )
    die_offset_max_mm: float = key(
        1.0, low=0.0, low_open=True, doc="bound on each die point's vertical offset (mm)"
    )
    bound_factor: float = key(
        2.0,
        low=1.0,
        high=1000.0,
        low_open=True,
        doc="material parameters and ram speed stay within [p0 / factor, p0 * factor]",
    )
    target_csv: str = key(
        "",
        doc="target for temperature_misfit (CSV with time_s, mean_temperature_K), "
        "force_misfit (CSV with stroke_mm, force_N) or shape_target (CSV with "
        "node, r_mm, z_mm)",
    )
    die_spline_controls: int = key(
        0,
        low=0,
        high=40,
        doc="free control heights of the 'die_spline' group: a clamped cubic B-spline of the "
        "top die's heights z(r) between design.die_spline_r0_mm and r1_mm, sampled onto the "
        "die's profile points there (0: no spline; with fixed ends at least 2, else 4)",
    )
    die_spline_r0_mm: float = key(0.0, low=0.0, doc="inner radius of the die_spline range (mm)")
    die_spline_r1_mm: float = key(
        0.0, low=0.0, doc="outer radius of the die_spline range (mm; 0: the die's largest radius)"
    )
    die_spline_fixed_ends: bool = key(
        True,
        doc="the spline's end heights stay at the die's heights at r0 and r1 (the profile "
        "stays continuous); false: they are design variables too",
    )
    die_spline_offset_max_mm: float = key(
        1.0, low=0.0, low_open=True, doc="bound on each spline control height's offset (mm)"
    )
    die_draft_deg: float = key(
        0.0,
        low=0.0,
        high=89.0,
        doc="least draft angle of the spline's walls from the press direction (deg; 0: none)",
    )
    die_fillet_radius_min_mm: float = key(
        0.0, low=0.0, doc="least fillet (curvature) radius of the spline (mm; 0: none)"
    )
    constraint_penalty: float = key(
        10.0,
        low=0.0,
        low_open=True,
        doc="weight of the die_spline constraints' exterior penalty: objective units per "
        "squared relative violation",
    )
    flash_radius_mm: float = key(
        0.0,
        low=0.0,
        doc="objective flash_volume: the material beyond this radius (mm; 0: die.part_radius_mm)",
    )
    press_capacity_N: float = key(
        0.0,
        low=0.0,
        doc="objective press_capacity: the press's capacity (N); the term is "
        "design.capacity_penalty x (max(0, F_peak - capacity) / capacity)^2",
    )
    capacity_penalty: float = key(
        1.0, low=0.0, low_open=True, doc="weight of the press_capacity term (objective units)"
    )
    lap_angle_deg: float = key(
        30.0,
        low=0.0,
        high=180.0,
        low_open=True,
        doc="objective lap: free-surface air wedges narrower than this (deg) at the end are "
        "penalized as (1 - angle / limit)^2, summed over the free-surface vertices",
    )
    terms: tuple[str, ...] = key(
        [],
        choices=tuple(o for o in OBJECTIVES if o != "weighted_sum"),
        doc="objective weighted_sum: its terms (any objective but weighted_sum)",
    )
    term_weights: tuple[float, ...] = key(
        [],
        doc="objective weighted_sum: the weight of each of design.terms, in their order (a "
        "process: then of each of design.operation_terms)",
    )
    operation_terms: tuple[str, ...] = key(
        [],
        doc="a process, objective weighted_sum: terms of named operations, "
        "'<operation>.<objective>' (peak_force, forging_work, press_capacity, flash_volume, "
        "die_fill, lap, mean_temperature; e.g. finisher.die_fill, blocker.press_capacity), "
        "after design.terms (those of design.objective_operation)",
    )
    optimizer: str = key(
        "lbfgs",
        choices=("lbfgs", "adam", "lhs_rsm", "cmaes"),
        doc="lbfgs, adam (optax, gradients), lhs_rsm (a Latin hypercube of "
        "design.samples_per_variable runs per variable, a quadratic response surface, its "
        "minimum verified by one more run per design.rsm_rounds) or cmaes (CMA-ES; "
        "design.population, design.cmaes_sigma)",
    )
    iterations: int = key(20, low=1, high=10000, doc="optimizer iterations")
    samples_per_variable: int = key(
        8, low=1, high=1000, doc="lhs_rsm: Latin hypercube runs per design variable"
    )
    rsm_rounds: int = key(
        1,
        low=1,
        high=100,
        doc="lhs_rsm: fit, minimize and verify rounds (each after the first refits with the "
        "verified runs added)",
    )
    population: int = key(
        0, low=0, high=10000, doc="cmaes: runs per generation (0: 4 + 3 ln n for n variables)"
    )
    cmaes_sigma: float = key(
        0.3,
        low=0.0,
        high=1.0,
        low_open=True,
        doc="cmaes: initial step size, as a fraction of each variable's bound box",
    )
    max_simulations: int = key(
        200, low=1, high=1_000_000, doc="lhs_rsm, cmaes: the most runs the optimizer may use"
    )
    seed: int = key(0, low=0, high=2**31 - 1, doc="lhs_rsm, cmaes: the random seed")
    learning_rate: float = key(
        0.05, low=0.0, low_open=True, doc="Adam step size in the scaled design variables"
    )
    step_max_fraction: float = key(
        0.25,
        low=0.0,
        high=1.0,
        low_open=True,
        doc="lbfgs: the most any variable moves in one step, as a fraction of its bound box "
        "(a restart's steepest descent moves the largest by this much); smaller where a step "
        "across the box overshoots an edge the design has to come back to (a robust design's "
        "billet volume)",
    )
    replan_distance: float = key(
        0.0,
        low=0.0,
        high=1.0,
        doc="a process: a design farther than this from the design the current plan (steps, "
        "meshes) was made at, in any variable as a fraction of its bound box, is evaluated "
        "on a new forward run's plan (0: a new plan only where the replay fails)",
    )
    robust: str = key(
        "",
        choices=("", "mean", "worst"),
        doc="a process: design for the mean or the worst objective over the scenarios of "
        "design.robust_friction x design.robust_die_temperature_K ('' = the nominal inputs)",
    )
    robust_friction: tuple[float, ...] = key(
        [],
        low=0.0,
        doc="design.robust: the friction coefficients (mu or m, of every die of every "
        "forming operation) of the scenarios ([] = as configured)",
    )
    robust_die_temperature_K: tuple[float, ...] = key(
        [],
        low=1.0,
        high=5000.0,
        doc="design.robust: the die temperatures (K, of every forming operation) of the "
        "scenarios ([] = as configured; coupled heat)",
    )


STUDY_PLANS = ("latin_hypercube", "sobol", "monte_carlo", "factorial")


@section("study")
@dataclass(frozen=True, kw_only=True)
class StudyConfig:
    """[study]: a design of experiments or a Monte-Carlo study (jaxform study): inputs,
    plan, responses (docs/doe.md)."""

    inputs: tuple[str, ...] = key(
        [],
        doc="the inputs: 'section.key = uniform(low, high)', 'normal(mean, std)', "
        "'lognormal(mu, sigma)' (of the key's log), or 'levels(a, b, ...)', any numeric key "
        "(values in its unit; each sample is the scene with these --set overrides)",
    )
    plan: str = key(
        "latin_hypercube",
        choices=STUDY_PLANS,
        doc="the samples: Latin hypercube, scrambled Sobol sequence, plain Monte Carlo "
        "(study.samples of each, from study.seed) or the full factorial of the levels",
    )
    samples: int = key(16, low=1, high=100_000, doc="samples of a random or Sobol plan")
    levels: int = key(
        3,
        low=2,
        high=100,
        doc="factorial plan: levels of an input given by a distribution (uniform: equally "
        "spaced from low to high; normal, lognormal: the quantiles (i + 1/2)/levels)",
    )
    seed: int = key(0, low=0, high=2**31 - 1, doc="seed of the random and Sobol plans")
    responses: tuple[str, ...] = key(
        ["force_N:max"],
        doc="what each sample reports: 'column:end', 'column:max' or 'column:min' of any "
        "history column (e.g. force_N:max, mean_temperature_K:end), 'fill' (die_fill at "
        "the end), 'flash' (flash_volume_mm3 at the end), 'laps' (number of laps found)",
    )
    gradients: bool = key(
        False,
        doc="also the exact gradient of each response in each input at each sample "
        "(inputs of the friction, speed and thermal design groups; no remeshing)",
    )
    retries: int = key(
        3,
        low=0,
        high=100,
        doc="times a sample whose worker died (killed, out of memory) runs again elsewhere",
    )
    batch: int = key(
        0,
        low=0,
        high=4096,
        doc="0: each sample is a run of its own (jaxform run: adaptive steps); B > 0: B "
        "samples per task as one vmapped program (jaxform.batch) over the base scene's fixed "
        "step schedule (inputs and responses as for study.gradients; same mesh)",
    )
