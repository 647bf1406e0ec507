"""Diagnosis: where does a model fail, and which physical effect is missing? (`manus diagnose`)

Every effect of the vocabulary that the model lacks is a candidate (and one it holds that can
grow: a cogging of one more order), as the effect itself allows: one that does not apply to
these joints (gravity on a prismatic axis), or that is offered only on top of another the model
lacks (Stribeck without Coulomb), is not tried and the notes say so; one that brings another
with it (a spring's preload is an offset) is tried with it. Each candidate is judged over
contiguous blocks of the recording, honestly:

- the recording's used rows are cut into contiguous blocks (a guard of one filter length at the
  seams left out of training: the filtered residual is correlated over about that long);
- significance, two tests combined by Simes' rule (either decides alone at half the level, both
  together at the level):
  the *score test* of the candidate's columns, summed per block against the model's residual:
  Wald's statistic with the blocks as clusters, its variance from the blocks' scores once the
  candidate is fitted without each (the cluster jackknife: noise only, so a strong effect does
  not inflate its own yardstick), its null distribution from random sign flips of the blocks,
  the statistic computed again in each (the blocks' noise scores flipped where many blocks
  share the columns' information, the wild cluster bootstrap; the scores themselves where a few
  hold most of it, an exact randomization test); one-sided in the coefficients its effect's
  physics signs (friction levels, a spring's stiffness: only what the physical sign explains
  counts, in the data and in every flip). A candidate with a non-linear parameter (a
  cogging order, a Stribeck velocity) takes the largest statistic over its search space (the
  values where its fit within its physical bounds leaves something off them), and so
  does every flip: the search is redone in each, and what it buys is paid for. Where the
  residual is correlated for longer than a block (a slow, unrecorded disturbance), blocks are
  merged until each spans `SPAN` correlation times (`significance.score_blocks`). And the
  *held-out errors*: for each block, the candidate's non-linear parameter searched and the model
  fitted on the other blocks only, the block predicted, the per-block log ratio of squared
  errors t-tested over the blocks. The score test has the power where the model is nearly right
  and the torque noisy; the held-out errors where the model is far from the data (several large
  effects missing: what is left is no noise, and a better prediction of every block still
  shows). A delay moves the torque and has no columns: the held-out errors alone. Each
  candidate is judged at `alpha` divided by the number of candidates of the step (Bonferroni);
  it must also predict the held-out blocks better than the model without it
  (`cv_error_reduction`, which also ranks the candidates);
- relevance: a candidate must explain at least `min_share` of the recorded torque (RMS: the
  torque it accounts for, √(e_before² − e_after²) in rel_error units), or remove at least half of
  the current error. A share of the torque, not only of the current error: on a noisy recording
  the error is mostly noise, and a real effect removes a small part of it. Or, per joint, relative
  to what is left there (`significance.on_joints`): significant on that joint's held-out errors
  alone, and `min_share` of that joint's torque, or a quarter of its remaining error (at least a
  tenth of a percent of its torque): on a seven-joint chain the shoulder's torque hides a wrist's
  effect, and on a model right to half a percent a real hump is a small share of the torque.

A candidate is proposed only when it is also physical: its fitted parameters obey its effect's
rules (friction b, Fc ≥ 0, Fs ≥ Fc, a spring k ≥ 0), its searched value does not sit on the edge
of its search range, and the recording can identify it (columns not already explained by the
model's own). Otherwise it is reported with the reason, not proposed. Where two candidates are
readings of the same columns on this recording (motion in one direction: a Coulomb level and an
offset are one constant), the verdict names both readings and proposes the one with fewer
physical assumptions once.

The verdict is the significant, proposable candidate with the lowest held-out error; a simpler
one (fewer parameters, searched ones counted) within one standard error of it is preferred.
The verdict must then encompass its rivals: a significant rival that adds a relevant share of the
torque, significantly, on top of it, while it adds nothing on top of the rival, takes its place
(a delay mimics an inertia through the viscous term; the data decide which holds the other).

After the verdict, the residual (of the model plus the verdict) is tested for structure no
effect of the vocabulary explains (`unexplained`, `leftover`): a smooth function of each joint's
position, velocity, position by direction of motion, position times the model's torque (a
torque ripple), of time, and a sinusoid at the residual's spectral peak, each fitted on the other
blocks and judged on the held-out one as above, and relevant as a candidate must be (`min_share`
of the torque).

Every candidate judged by its columns also states its *detection limit* on this recording
(`detectable`; `Diagnosis.detection_limits`): the share of the recorded torque (RMS) it would have
to explain, beyond what the model's own terms absorb, for its score test to find it 4 times in 5
(`scores.detectable`, from the same blocks' noise; at least `min_share`). A null verdict says no
more than that: an effect under its limit passes unseen. (A delay and a mode are judged
otherwise and state none.)

`compliance` is judged in the frequency band where it lives (see `modes`).

Modules, each importing only those before it: `scores` (the score test), `significance`
(held-out errors, Simes' rule), `modes` (a structural mode from the frequency response),
`context` (what a step judges in), `candidates` (each candidate judged), `oe_judging` (the
candidates judged by output error's positions where the fit is OE), `leftover` (what no effect
explains), `verdict` (`diagnose`: the step's verdict), `discover` (the loop).
"""
