"""`TrainConfig`: every setting of a training run, flat, so a checkpoint stores it as a dict.

The defaults are the reference 3DGS implementation's (Kerbl et al. 2023) unless noted.
Densification settings are read by the strategy named in `strategy` (`addon/core/train/strategies`).
"""

from __future__ import annotations

from dataclasses import dataclass

# The densification strategies by name (`strategies.STRATEGIES` maps each to its class; kept
# here too so that argument parsers and UI lists need not import the kernels), the default
# first.
STRATEGY_NAMES = ("auto", "mcmc", "default")


@dataclass
class TrainConfig:
    # A fixed number of steps; 0: until done (not in the reference): `Trainer.run()` ends once
    # the PSNR on the held-out views (with none, on up to 8 training views), measured every
    # `stop_check_every` steps, gained less than `stop_below_db_per_minute` per minute of
    # work over the last `stop_window_seconds` of work of checks, at two checks in a row
    # (`stopping.py`; `Trainer.converged` then says so; 0: never), or at `max_steps`. Work is
    # each step's modelled cost in seconds of one reference core (`stopping.step_work`), not a
    # clock: the same run stops at the same step on an idle and on a busy machine. The run
    # then ends with the best state its checks saw (`Trainer.best`).
    steps: int = 0
    max_steps: int = 30_000
    stop_below_db_per_minute: float = 0.1
    stop_check_every: int = 500
    stop_window_seconds: float = 60.0
    # Once the gain stalls, a run until done trains `anneal_steps` more with every learning rate
    # decaying exponentially to `anneal_to` of its value, then stops: the held-out PSNR of a
    # model still moving at full rates swings by tenths of a dB from check to check (cup from
    # step 2000, every 100 steps: 27.71 to 28.70 dB at full rates, 28.32 to 28.65 annealed).
    anneal_steps: int = 500
    anneal_to: float = 0.01
    max_gaussians: int = 300_000
    sh_degree: int = 3
    seed: int = 0
    threads: int = 0
    antialiased: bool = False
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lambda_dssim: float = 0.2
    # Learning rates (3DGS defaults); the position rate is times the scene extent.
    position_lr_init: float = 1.6e-4
    position_lr_final: float = 1.6e-6
    position_lr_max_steps: int = 30_000
    sh_dc_lr: float = 2.5e-3
    sh_rest_lr: float = 2.5e-3 / 20
    opacity_lr: float = 2.5e-2
    scaling_lr: float = 5e-3
    rotation_lr: float = 1e-3
    sh_degree_interval: int = 1000
    # Every learning rate (the position rate's decay included) times a factor that goes
    # exponentially from `lr_scale_start` at step 0 to `lr_scale_end` at `lr_scale_steps`,
    # then stays (not in the reference, whose rates are tuned for 30k steps). Twice the rates at
    # the start, the reference's from step 2000: cup, 1 thread, defaults, held-out PSNR at
    # 15 / 23 / 30 CPU s, mean of seeds 0, 1, 2: 27.23 / 27.83 / 28.07 dB against 26.36 / 27.38 /
    # 27.64; beer level or better at 10 to 40 s (docs/benchmarks/training.md, "Learning-rate
    # schedule"). 2x throughout no better than 1x by 23 s; 3 to 0.5 0.25 dB better on cup but
    # 0.5 to 1.2 dB worse on beer from 25 s (its rates stay halved). 3 to 1 was level with 2 to
    # 1 while "auto" grew 5 % an interval; with its 10 % (`auto_growth`) it is better on cup and
    # beer (docs/benchmarks/training.md, "Issue 17's one-thread target").
    lr_scale_start: float = 3.0
    lr_scale_end: float = 1.0
    lr_scale_steps: int = 2000
    # Coarse to fine (not in the reference): the first steps train on images halved
    # `coarse_levels` times (box-filtered), the resolution doubling at even intervals until full
    # at step `coarse_until` (or half of `steps`, if sooner). 0 levels: off. On by measurement
    # (docs/benchmarks/training.md, "Strategies"): a better held-out PSNR
    # per CPU second on cup, beer and the demo scene with the "default" strategy.
    coarse_levels: int = 2
    coarse_until: int = 1000
    coarse_min_side: int = 32  # never below this many pixels a side (demo, 120x90: worse)
    # Densification: which strategy (a name in `strategies.STRATEGIES`), and its settings
    # (the "mcmc" strategy reads densify_from/until/every, prune_opacity and max_gaussians too).
    strategy: str = "auto"
    densify_from: int = 500
    densify_until: int = 15_000
    densify_every: int = 100
    densify_grad_threshold: float = 2e-4
    percent_dense: float = 0.01
    opacity_reset_every: int = 3000
    prune_opacity: float = 0.005
    # After the first opacity reset, Gaussians larger than this fraction of the scene extent are
    # pruned. The reference uses 0.1; with a budget on a small scene (cup) that keeps deleting
    # background Gaussians the views need (held-out PSNR 28.1 vs 30.1 dB at step 4000), so 0.3.
    # 0 disables it.
    prune_large_fraction: float = 0.3
    # Gaussians inside the empty ball around a training camera (`free_space.FreeSpace`: this
    # fraction of the distance from its centre to the nearest sparse point) and out of its view
    # are pruned at each densification ("mcmc"/"auto": relocated as dead ones are). The demo
    # scene, exact cameras, seed 1: held-out 25.6 dB without (a haze in front of the held-out
    # cameras), 28.1 with; cup 31.1 / 31.3 (docs/benchmarks/reconstruction.md). 0: off.
    free_space_fraction: float = 0.9
    initial_opacity: float = 0.1
    # The "mcmc" strategy (strategies/mcmc.py): the reference values of 3DGS-MCMC.
    mcmc_growth: float = 0.05          # Gaussians added per densification step, of the count
    mcmc_noise_lr: float = 5e5         # position noise, times the position learning rate
    mcmc_opacity_reg: float = 0.01
    mcmc_scale_reg: float = 0.01
    mcmc_initial_opacity: float = 0.5
    mcmc_initial_scale: float = 1.0    # times the 3-NN scale (the paper's code; gsplat uses 0.1)
    # The "auto" strategy (strategies/auto.py): MCMC growing while growth pays. After an interval
    # that grew the count by a fraction g, the training loss (per view) must have fallen by at
    # least `auto_gain_per_growth` x g, relative, in the interval; `auto_patience` misses in a row
    # settle the count (until the resolution rises). 1: 10 % more Gaussians (`auto_growth`)
    # must come with 10 % less loss (on cup at full size the loss falls 3 to 10 % an interval
    # from step 1000 to 2500 while the count grows; measured with 5 % growth, 0.2 grew it past
    # 24,000 by step 2500 and on). 10 % rather than 5 %: the count settles sooner and a given
    # PSNR comes sooner; 15 % and 20 % overshoot (slower steps), 10 % with 0.5 here too.
    auto_gain_per_growth: float = 1.0
    # Below this many Gaussians per pixel of a training image (at its resolution level) it
    # grows whatever the loss does, by `auto_floor_growth` an interval (strategies/auto.py:
    # the count scales with the image size; 0: no floor).
    auto_gaussians_per_pixel: float = 0.25
    auto_floor_growth: float = 0.20
    # Above this many pixels per training image "auto" densifies as the reference does
    # (strategies/auto.py `LargeImageStrategy`: 5 dB better held-out at equal CPU time on the
    # demo scene at 480x360; issue 25). 0: never.
    auto_reference_above_pixels: int = 100_000
    # "auto" on large images (`LargeImageStrategy`) sizes the model by contribution, not by the
    # ceiling: every `importance_every` steps from `importance_from` while it densifies (not in
    # the first `stop_check_every` steps after an opacity reset), the Gaussians that together
    # carry the smallest `importance_prune_weight` of the blending weight on the training views
    # are pruned (`importance.py`; 0: never). On the demo scene at 480x360, step 1,500, 2 % of
    # the weight was 43 % of the Gaussians, and pruning them moved the held-out PSNR by +0.02 dB
    # before any further training (5 %: 57 %, -0.36 dB). Pruning 2 % every 500 steps: 33,674
    # Gaussians and 29.52 dB at step 2,500 against 93,516 and 28.49 dB without; 5 %: 22,680
    # and 27.95 dB (docs/benchmarks/training_sizes.md, "Only the Gaussians a scene needs").
    importance_prune_weight: float = 0.02
    importance_every: int = 500
    importance_from: int = 1000
    # With importance pruning, no opacity reset (and so no pruning of large Gaussians, which the
    # reference does after its first reset): the reset's job, letting what the views do not need
    # fade so that the opacity threshold prunes it, is done by contribution. On the demo scene at
    # 480x360 the reset at step 3,000 took the held-out PSNR from 28.49 dB (step 2,500) to 4, and
    # it was not back by step 8,000 (28.44), the run going on with ever more Gaussians; without
    # it, 29.82 dB at the end with 33,935 (beer at 360x640: 23.85 dB with 17,172 at the end,
    # 23.18 with 84,619 before, whose best check was 24.44).
    importance_replaces_reset: bool = True
    # ... and it stops growing (clone and split; pruning goes on) once `auto_patience` stopping
    # checks in a row at full resolution gained less held-out PSNR than this many dB per doubling
    # of the count since the check before (runs until done only; 0: grows to `densify_until`).
    auto_settle_db_per_doubling: float = 0.0
    auto_patience: int = 2
    auto_growth: float = 0.10  # the count added an interval while growing (MCMC's is 5 %)
    # It relocates and grows from this step on, not `densify_from` (MCMC's 500): on cup, 1 thread,
    # starting at 100 reached 27.7 dB held-out at 25 s of CPU against 26.7 dB from 500.
    auto_densify_from: int = 100
    max_initial_points: int = 50_000  # the 3-NN scale estimate is quadratic in this
    # Adam over only the Gaussians each step drew (gsplat's `visible_adam`): the others keep
    # their parameters and moments. None: the strategy's choice (`Strategy.sparse_adam`), on for
    # "mcmc" and "auto" (cup, 2000 steps, 2 seeds: +1.0 dB with mcmc, +0.6/+0.7 dB with auto),
    # off for "default" (-0.5 to -0.7 dB; docs/benchmarks/training.md, "Training kernels").
    sparse_adam: bool | None = None
