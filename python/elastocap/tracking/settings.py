"""The tracker's tuned constants (issue 15), in one module so that every family of the
tracker reads the same values and a bench or a test can override one (each is read at call
time as ``settings.NAME``). Measured on the textured capture's tuning seed 0
(benches/README.md, the sections of branches tracking and track3-track6)."""

from __future__ import annotations

from elastocap.tracking.flags import TrackFlag

# The matcher's covariance holds the noise of one match, not the drift of a chain of
# them: each view gets this standard deviation (pixels) on top in the intersection.
FLOOR = 0.1
# Least RMS gradient of a patch along its weakest direction, in multiples of the image's
# noise level (smooth printed textures are weak at 11 px).
TEXTURE_OVER_NOISE = 1.0
# The same floor for a view already tracked (hysteresis): a seed's patch turns and changes
# shading from frame to frame, and its weakest gradient wanders below the seeding floor
# without the match going wrong. Measured on the textured capture (seed 0, frame pairs
# started at the truth, views at least 12 px inside the silhouette): the floor at 1.0 x
# noise refuses 51% of them, at 0.5 x 12%, for a median error of 0.12 and 0.14 px.
KEEP_TEXTURE_OVER_NOISE = 0.5
# Least correlation of the box search's peak (a start for least-squares matching).
BOX_CORRELATION = 0.5
# Largest correction of a frame-to-frame match by its anchor, pixels.
ANCHOR_REACH = 1.5
# The anchor's match (its correction, and its rescue with ANCHOR_REFINE_RESCUE) refined with a richer model after the affine
# match converged: ``match_patches(refine=)``'s mapping (second-order warp terms, a gain
# that varies across the patch), or None for the affine match. On a limb that turns the
# affine model settles tenths of a pixel off the material point (benches/README.md,
# track27 and lsm28). Off: see lsm28 for the measurements.
ANCHOR_REFINE: dict[str, object] | None = None
# Whether the anchor's rescue of a lost view uses it too (its covariance, the richer
# model's normal equations without the sandwich, then weighs the view in the intersection;
# lsm28 measured the correction alone as its variant).
ANCHOR_REFINE_RESCUE = False
# With ANCHOR_REFINE, the anchor's correction is the affine match's centre plus the richer
# model's departure from it smoothed over frames (exponentially, this weight on the newest;
# restarted when the patch is cut again); 1: the richer centre as it is (lsm28's variant V).
# The departure (the affine model's slide) changes slowly, the richer centre's noise every
# frame: unsmoothed it raised the frame-to-frame jitter of the tracks by a fifth and ended
# tracks in the trajectory checks (benches/README.md, lsm29). Costs a second affine match
# per anchor view.
ANCHOR_REFINE_SMOOTH = 1.0
# With the smoothed departure (ANCHOR_REFINE_SMOOTH < 1), the richer stage runs on a view
# only from this many corrections after its patch was cut, and then every this many
# corrections; in between the affine centre carries the last smoothed departure. The
# departure grows slowly with the anchor's age and the smoothing already spreads it over
# frames, while the richer stage costs ~7x the affine match (benches/README.md,
# anchorcost1). 0 and 1: every correction (lsm29's W).
ANCHOR_REFINE_MIN_AGE = 0
ANCHOR_REFINE_EVERY = 1
# Gauss-Newton iterations of the frame-to-frame match: from the box search's start a
# match that will converge does so in a few; the rest wander along the weak direction of a
# smooth texture (measured on the textured capture: 8 instead of 15 keeps 1.6% more views
# and costs 23% less CPU).
STEP_ITERATIONS = 8
# Largest distance of a rescued view from its linear prediction, pixels.
RESCUE_REACH = 3.0
# A lost point is looked for again for this many frames after it was lost...
REVIVE_FRAMES = 15
# Its position is predicted by the rigid motion of its neighbours since it was lost
# (REVIVE_RIGID) or by their median displacement. The rigid motion predicts better (seed
# 0: attempts within 2 px-eq of the truth 8% -> 24%, revivals 75 -> 110) but the points it
# brings back are lost again: through 33.46 -> 33.49%, kept 3-D beyond 5 px-eq 3.28 ->
# 3.36% (benches/README.md, branch track9), so it is off.
REVIVE_RIGID = False
# The neighbours that predict a lost point taken from its own body part (revival.own_part:
# of the REVIVE_CANDIDATES nearest in the 6-D space of the last frame before the loss and
# the point's seeding frame, those whose distance to it changed by less than RIGID_STRETCH
# pixels), moved by their rigid motion (REVIVE_RIGID then does not apply). Tuning seeds 0,
# 2, 3, 8, 9 against the true surface point (benches/README.md, branch track15), against the
# nearest points' median shift: revivals' predictions within 2 px-eq of the truth 25-50% ->
# 56-72%, revivals +8-50%, kept 3-D positions beyond 5 px-eq (mean) 2.25 -> 2.03%, through
# 29.65 -> 29.73% (the points found come back and are lost again).
REVIVE_OWN_PART = True
REVIVE_CANDIDATES = 16
# With REVIVE_OWN_PART: the anchor patches searched warped by the affine of their part's
# motion since they were cut (revival_warp.anchor_affines), the plain search kept where it
# finds a view the warped one does not. Off: it finds no more (seeds 0 / 8: revivals 115 ->
# 113 / 99 -> 103, kept 3-D beyond 5 px-eq 1.95 -> 1.96% / 2.48 -> 2.48%); the anchors that
# fail where the prediction is right fail for another reason (branch track15).
REVIVE_WARP = False
# Least correlation of a revived view's match (the tracker's min_correlation when lower).
# 0.6 (seeds 0 / 2): through 35.07 -> 35.52% / 25.45 -> 25.48%, kept 3-D beyond 5 px-eq
# 1.95 -> 1.96% / 2.48 -> 2.62% (branch track15).
REVIVE_CORRELATION = 1.0
# A lost point's anchors cut again from its last tracked frame when it is lost (on seed 0,
# of the anchor views searched where the prediction is within 2 px-eq and the camera sees
# the point, those cut 0-2 frames before are found 55% of the time, 20+ frames 8.5%).
REVIVE_LAST_PATCH = False
# ... by its anchors, in a box of this half-side (pixels) around the projections of its
# position predicted from its neighbours' motion.
REVIVE_RADIUS = 8
# The revived intersection must land within this many pixel equivalents of the
# prediction (the box above only has to find the start). A match that converged to a
# nearby wrong place stays there for the point's whole life, its anchor holding it: on
# seed 0, with the bound at REVIVE_RADIUS, the revivals within 4 px-eq of the prediction
# were 8% beyond 5 px-eq on the revival frame and 2.5% after, those 4-8 px-eq away 21%
# and 18%; with the bound at 4 the revived positions are 2.6% and 1.6% beyond (the others
# 3.4%; benches/README.md, branch track9).
REVIVE_REACH = 4.0
# Largest reprojection residual of a revived point's views, pixels (with two views, the
# distance from the epipolar line: a wrong match found far from the prediction).
REVIVE_RESIDUAL = 1.5
REVIVE_RECUT = False
# Least cosine between a lost point's predicted normal and the direction to a camera it is
# looked for in (a surface coming back into view is first seen at grazing angles).
REVIVE_FACING = 0.0
# Largest distance of a re-acquired view from the projection of the point, pixels: a
# point held by one stereo pair has a poor depth, whose error shows in a camera 45-90
# degrees away as an offset of pixels along the epipolar line (the intersection with the
# new view then checks it and fixes the depth).
REACQUIRE_TOLERANCE = 1.5
# The re-acquisition searches (NCC box of this half-side, pixels, with the patch warped by
# the neighbours' plane into the other camera) before its least-squares match; 0: the
# match alone, started at the projection. A found view may lie this far from the
# projection (the intersection with the view then checks it).
REACQUIRE_RADIUS = 0
REACQUIRE_SEARCH_TOLERANCE = 3.0
REACQUIRE_ITERATIONS = 20
# Hand a tracked point over to another stereo pair predicted to see it
# (:mod:`elastocap.tracking.handover`) once its own pair is losing it: a held view's
# surface turned below HANDOVER_WHEN (cosine between the normal and the direction to the
# camera). The patch at its projection in the camera of that pair facing it more is
# matched into its partner (within HANDOVER_TOLERANCE pixels), the point moved along its
# first held view's ray onto the surface that pair sees (HANDOVER_ITERATIONS times; at
# most HANDOVER_REACH pixel equivalents), and the new views kept when they intersect with
# the held ones. HANDOVER_FACING: least cosine of the new cameras. Seed 0
# (benches/README.md, branch track10): through 32.8 -> 34.3%, kept 3-D beyond 5 px-eq
# 3.31 -> 2.86%, median RMS 0.360 -> 0.385 px; handing over every point a free pair sees
# (HANDOVER_WHEN above 1): 36.4%, 4.82%, 0.534 px (the held pair's depth error shows as an
# image error in the new cameras). Off: the image figures rise with it (median RMS
# +0.025 px, through and RMS <= 0.5 px 16.9 -> 15.3%, kept image beyond 5 px 0.71 ->
# 1.10%), which the brief it was made for ruled out.
HANDOVER = False
HANDOVER_TOLERANCE = 3.0
HANDOVER_FACING = 0.0
HANDOVER_ITERATIONS = 3
HANDOVER_REACH = 6.0
HANDOVER_WHEN = 0.3
# Re-acquired views of a tracked point kept only when they intersect with its held ones.
CONFIRM_REACQUIRED = True
# Start shapes of cross-camera matches from the plane of the neighbouring tracked points
# (else from the direction of the cameras that see the point).
FITTED_NORMALS = True
# Re-acquire and revive a point only in the cameras predicted to see it
# (:mod:`elastocap.tracking.visibility`), not in every camera whose silhouette it falls in.
PREDICT_VISIBILITY = True
# Re-tie each tracked point's held views to its reference view by spatial matching every
# frame (:mod:`elastocap.tracking.retie`): a match within RETIE_TOLERANCE pixels of the
# tracked view replaces it. On seed 0 the kept 3-D positions beyond 5 px-equivalents
# 8.3 -> 4.4% for 0.6 point of "through". Removing the views whose match lies farther than
# RETIE_DROP pixels (and, with RETIE_DROP_FAILED, those whose match fails) takes the 3-D
# figure lower at a larger cost: 0.5 px 3.0% / through 29.7%; with the failures 1.7% /
# 25.2% (infinite: kept as tracked; benches/README.md, branch track7).
RETIE = True
RETIE_TOLERANCE = 1.5
RETIE_DROP = float("inf")
RETIE_DROP_FAILED = True
# The view the others are re-tied to: "anchor", the one whose anchor is oldest (seed 0:
# through 33.3%, kept 3-D beyond 5 px-eq 3.84%, image 0.65%), or "correlation", the one of
# best correlation (33.4%, 4.38%, 1.07%).
RETIE_REFERENCE = "anchor"
# A held view predicted hidden (outside its silhouette, behind another tracked point,
# and with HIDDEN_FACING above -1 its surface turned away) on HIDDEN_FRAMES consecutive
# frames is ended (0: never; :mod:`elastocap.tracking.hidden`); with HIDDEN_EVIDENCE only
# where its own match agrees: the frame-to-frame correlation below HIDDEN_CORRELATION or
# the re-tie moving it farther than HIDDEN_SHIFT pixels (or failing). With HIDDEN_SET_ASIDE
# a point that keeps two other views keeps the hidden one tracked but out of the
# intersection. Seed 0 (benches/README.md, branch track8): through 33.3 -> 32.8%, kept
# 3-D beyond 5 px-eq 3.84 -> 3.31%; ended at once (1 frame, no evidence) 31.7% / 2.83%.
HIDDEN_FRAMES = 2
# HIDDEN_FACING 0.1 (session 30, branch kept1; -2.0 before): a view whose surface turns to
# grazing (cosine to its camera below 0.1 by the tracker's fitted normal) is ended like an
# occluded one (2 frames, the evidence above). A pair's views of a surface turning away
# slide to its rim and hold there: on tuning m15 the head turning away from cameras 4 and 5
# over its last twelve frames gave 101 of the 213 kept 3-D positions beyond 5 px-eq, 99 of
# them held only by cameras that no longer saw the point. Against -2.0 (benches/README.md,
# kept1): kept 3-D beyond 5 px-eq m15 2.168 -> 1.519%, m41 0.823 -> 0.665%; through -0.61 /
# -0.38 point; 0.2: 1.353 / 0.663%, through -1.11 / -0.87; 0.05: m15 1.914%, through 0.
HIDDEN_FACING = 0.1
HIDDEN_EVIDENCE = True
HIDDEN_CORRELATION = 0.9
HIDDEN_SHIFT = 0.3
HIDDEN_SET_ASIDE = False
# The reported covariance with the drift of the views (:mod:`elastocap.tracking.drift`):
# (DRIFT_SCALE[0] + DRIFT_SCALE[1] f) S + pixel^2 (DRIFT_VARIANCE[0] + DRIFT_VARIANCE[1] f)
# I, f the most cuts again of the point's anchors; calibrated on seed 0 (median
# Mahalanobis distance 5.7 -> 1.7; benches/README.md, branch track8). DRIFT False: the
# intersection's covariance as it is.
DRIFT = True
DRIFT_SCALE = (0.06, 1.0)
DRIFT_VARIANCE = (0.07, 0.22)
# The reported positions fused with the prediction of their RIGID_NEIGHBOURS nearest
# tracked points' rigid motion since the point was seeded, isotropic with RIGID_SIGMA
# pixels at the point (:mod:`elastocap.tracking.rigidity`; with DRIFT: the intersection's
# weight is the drift covariance). Output only: the tracker's state and the views are the
# intersection's. Against the true surface point (benches/README.md, branch track11): kept
# 3-D positions beyond 5 px-eq, seed 0 (tuning) 3.21 -> 2.11%, held out seed 2 3.67 ->
# 3.57%, seed 3 2.56 -> 2.16%; through and every image figure unchanged. Tuned offline on
# seed 0 (12 neighbours: sigma 1 3.12%, 2 2.36%, 3 2.28%; sigma 2: 20 neighbours 3.26%).
# Where the neighbours straddle two body parts the prediction is wrong (seed 2: 215
# positions broken for 228 fixed). RIGID_BOTH_FRAMES > 0: the neighbours nearest in the
# 6-D space of where they are now and (times this) where they were on the point's seeding
# frame, so a part that has come close since is not taken; RIGID_STRETCH finite: among the
# RIGID_CANDIDATES nearest so, those whose distance to the point changed by less than this
# many pixels since (branch track12, tuned offline on seeds 0, 2, 3 against the true point:
# 8 neighbours, sd 2 px, nearest now 2.11 / 3.57 / 2.16%; 6-D 2.02 / 3.50 / 2.13%; 6-D and
# stretch < 8 px, sd 2.5 px 2.05 / 2.77 / 1.75%; true-part neighbours 1.89 / 2.95 / 1.57%;
# held out, fresh seeds 8 and 9: nearest now 3.50 / 2.36%, these 2.77 / 1.98%).
RIGID = True
RIGID_NEIGHBOURS = 8
RIGID_SIGMA = 2.0
RIGID_BOTH_FRAMES = 1.0
RIGID_CANDIDATES = 16
RIGID_STRETCH = 8.0
# The prediction's covariance times max(1, m^2 / RIGID_GATE^2), m the Mahalanobis distance
# between the prediction and the intersection (in the sum of their covariances; infinite:
# never). Where the two disagree by much more than both allow the prediction is the one
# more often wrong (branch track14: gating it rather than the views' covariance takes the
# kept 3-D positions beyond 5 px-eq down, trusting it more takes them up), so its pull
# falls as the disagreement grows. Tuned offline on seeds 0, 2, 3 with RIGID_SIGMA (2.5,
# no gate: 2.05 / 2.77 / 1.75%; 2.5, gate 2: 1.78 / 2.20 / 1.41%; 2.0, gate 2: 1.63 / 2.20
# / 1.46%; 2.0, gate 3: 1.67 / 2.35 / 1.63%; 1.5, gate 2: 1.60 / 2.30 / 1.54%; seeds 8
# and 9: 2.77 / 1.98% -> 2.35 / 1.26%). Held out, fresh seeds 12 and 13: 3.52 / 2.14% ->
# 2.86 / 1.83%; through and every image figure unchanged (output only). The elastic fit
# with tracks (with RIGID_PASSES 2): seed 6 drift 3.67 -> 3.92% (ratio 0.486 -> 0.520),
# seed 7 3.89 -> 3.84% and its lost frame held (benches/README.md, branch track14).
RIGID_GATE = 2.0
# The fusion repeated with the neighbours' motion fitted to their fused positions of the
# pass before (1: once): a neighbour whose own depth drifted moves its neighbours'
# predictions less. Tuned offline on seeds 0, 2, 3, 8, 9 with the gate (branch track14):
# one pass 1.63 / 2.20 / 1.46 / 2.35 / 1.26%, two 1.54 / 2.05 / 1.51 / 2.11 / 1.23%, three
# 1.53 / 2.10 / 1.52% (0, 2, 3).
RIGID_PASSES = 2
# The reported covariance (after the fusion) times this. Against the true surface point the
# fused covariance is optimistic: median Mahalanobis distance 1.93 / 2.04 / 1.91 on seeds 0,
# 2, 3 (branch track12), where a calibrated 3-D Gaussian gives 1.54; 1.6 calibrates the
# median. Left at 1: the fits weigh tracks by these covariances (the elastic fit under a
# Cauchy loss whose scale they set), and their weights were tuned at 1. With the gated
# fusion (branch track14) the medians are 1.97 / 2.07 / 1.94 and 1.7 calibrates them (1.51
# / 1.59 / 1.49), 8-10% still beyond the chi-square 99% point (1% if calibrated); the
# tail is better met by the drift's isotropic term: DRIFT_VARIANCE (0.25, 0.4) gives 1.45
# / 1.52 / 1.42 and 6.5 / 7.9 / 6.4% with the 3-D figure within 0.03 point. Neither is
# set, for the same reason.
COVARIANCE_SCALE = 1.0
# Positions whose standard deviation along the weakest direction of that covariance
# exceeds this many pixel equivalents are withheld (flag UNCERTAIN); infinite: kept. The
# tracker follows them on, but a run resumed from its files restarts their trajectory
# filters (the files hold no position for them).
UNCERTAIN_SD = float("inf")
# Reported positions withheld as SLID (:mod:`elastocap.tracking.rigidity`,
# ``rigid_residuals``): the intersection farther across its rays from where its neighbours'
# rigid motion since its seeding frame puts it than SLIDE + SLIDE_SCALE times the
# neighbours' own held-out residual to that motion, pixel equivalents; with SLIDE_STICKY on
# every later frame of the track too. Infinite: off. Output only. Tuned offline on seeds 0,
# 2, 3 against the true surface point (benches/README.md, branch track17): kept 3-D beyond
# 5 px-eq 1.45 / 1.93 / 1.27% -> 0.90 / 1.08 / 0.87%, through 35.1 / 25.5 / 25.9% -> 33.8 /
# 24.5 / 25.5% (4 + 1 x: 1.01 / 1.18 / 0.98%, through -0.7 / -0.5 / -0.4; 3 + 2 x: 1.11 /
# 1.28 / 1.00%, -0.6 / -0.4 / -0.3; not sticky, 4 + 0.5 x: 1.05 / 1.24 / 0.98%, -1.2 /
# -1.0 / -0.4). A quarter to a half of the positions withheld are beyond 5 px-eq, most
# of the others beyond 2.
SLIDE = 4.0
SLIDE_SCALE = 0.5
SLIDE_STICKY = True
# The same prediction along the rays (:mod:`elastocap.tracking.depth_slide`): positions whose
# intersection lies farther than SLIDE_ALONG pixel equivalents from it along the direction
# to their cameras (the pair's depth slid: a narrow pair seeing the surface obliquely) on
# SLIDE_ALONG_FRAMES consecutive frames are withheld as SLID too, sticky with SLIDE_STICKY;
# with SLIDE_ALONG_LEAVES such points leave their neighbours' rigid fits (the fusion's and
# both checks' predictions) from the next frame on: withheld, they are still tracked, and
# left in they pull their neighbours' predictions after them. Infinite: off (main's tracks
# before session 33). Tuning captures m15 / m41, with SEED_NEEDS_PAIR, true reference, all
# points (benches/log/139-kept2.md): kept 3-D beyond 5 px-eq 1.519 / 0.665% -> 0.970 /
# 0.537%, through -0.41 / -0.53 point, through with RMS <= 0.5 px -0.29 / -0.32 (8, leaving);
# 0.964 / 0.520%, -0.56 / -0.95 (7, leaving); 0.830 / 0.476%, -0.87 / -1.58 (6, leaving);
# 0.953 / 0.540%, -0.87 / -1.37 (6, staying); 1.034 / 0.592%, -0.26 / -1.16 (5 on 2 frames,
# staying). Withholding costs a through track its through.
SLIDE_ALONG = 8.0
SLIDE_ALONG_FRAMES = 1
SLIDE_ALONG_LEAVES = True
# Reported positions withheld as OUTSIDE (:mod:`elastocap.tracking.silhouette`): projecting
# farther than this many pixels outside the silhouette of a camera whose image they fall in
# (any camera, not only those holding the point's views); infinite: off. Output only. Most
# kept positions beyond 5 px-eq after the fusion and SLID are off along the rays, the
# majority in front of the surface, and a camera seeing the limb from the side sees that
# as a point beside its silhouette. Tuning seeds 0, 2, 3, 14, 15 against the true surface
# point (benches/README.md, branch track18), main's reported positions and these on the same
# runs: kept 3-D beyond 5 px-eq 0.90 / 1.08 / 0.87 / 0.83 / 2.32% -> 0.76 / 0.96 / 0.77 /
# 0.66 / 2.22%, through_span -0.3 to -0.9 point (through, which a track's withheld first
# frames do not count against, -0.02 to +0.4); 2 px: 0.71 / 0.97 / 0.76 / 0.62 / 2.16%, -0.5 to
# -2.6 points of through; 4 px: 0.77 / 1.01 / 0.77 / 0.67 / 2.27%. Some 40-60% of the
# positions withheld at 3 px are beyond 5 px-eq. Held out (seeds 16, 17): 1.07 / 1.21% ->
# 0.88 / 1.05%, through_span -0.2 / -0.3 point. The elastic fit with tracks: within its
# noise (seeds 1, 10, 18, 19: drift -0.18 to +0.19 point, two better, two worse).
OUTSIDE = 3.0
# Positions whose drift covariance before the rigid fusion (``DRIFT_SCALE``: the views' anchor
# cuts) has a standard deviation along its weakest direction above this many pixel
# equivalents are withheld (flag UNCERTAIN); infinite: off. Unlike UNCERTAIN_SD (after the
# fusion, which shrinks it towards the neighbours' prediction) it sees a neighbourhood whose
# depth drifted together (seed 15's worst frames). Off: on the tuning seeds the kept 3-D
# figure reaches 1% on seed 15 only near 3.5 px-eq, for some 4 points of through
# (benches/README.md, track18).
UNCERTAIN_DRIFT_SD = float("inf")
# The frame-to-frame step's failed views searched again (:mod:`elastocap.tracking.prediction`):
# at the median displacement of the views of their RESEARCH_NEIGHBOURS nearest points in
# 3-D (within RESEARCH_REACH pixel equivalents; at least RESEARCH_MIN_NEIGHBOURS), and
# those without such neighbours in a box of RESEARCH_WIDE_RADIUS pixels (0: not) around
# their own prediction. Tuning seeds 0, 2, 3, 8, 9 against the true surface point
# (benches/README.md, branch track13): through +0.7 to +1.5 points, through with RMS <= 0.5
# px +0.1 to +0.7, median RMS +0.02 to +0.05 px, kept 3-D beyond 5 px-eq -0.20 to +0.48
# points (mean +0.16); held out seeds 12, 13: through +1.2 / +1.4, kept 3-D +0.12 / +0.36.
# False: the step's failures stay lost (main's tracker before this branch, exactly).
# Off by default since the merge (benches/README.md, "Session 18, lead"): with the revival
# and the gated fusion merged beside it, it lifts through and through with RMS <= 0.5 px
# on the tuning seeds (30.2 / 12.9% against 29.7 / 12.6% without it) but costs the kept 3-D
# figure (1.82 against 1.54%), and the elastic fit with tracks drifts more with it on the
# fit's tuning seeds 1 and 7 (ratio 0.543 / 0.383 against 0.504 / 0.375).
RESEARCH = False
RESEARCH_NEIGHBOURS = 8
RESEARCH_MIN_NEIGHBOURS = 3
RESEARCH_REACH = 30.0
RESEARCH_WIDE_RADIUS = 24
# The second search's patch side, pixels (0: the step's): a forearm is about as wide as the
# step's 15 px patch, whose corners then hold the surface behind it, which moves otherwise.
RESEARCH_SIZE = 11
# A stricter acceptance of the wide box's finds (branch track16; the wide box is what costs
# the kept 3-D figure): the least correlation of a find there (None: the tracker's), and the
# largest distance, pixels, of a find the intersection used from its projection (infinite:
# the intersection's own bound; a farther find is dropped and its point intersected again).
# Unset: 0.85 and 0.5 px leave every figure within 0.03 point of RESEARCH alone on m0 and
# m2 (kept 3-D 1.33 / 2.32% against 1.33 / 2.35%): the wide box's finds are not what costs
# the kept 3-D figure (benches/README.md, branch track16).
RESEARCH_WIDE_CORRELATION: float | None = None
RESEARCH_WIDE_RESIDUAL = float("inf")
# The frame-to-frame step's templates cut at depth edges (:mod:`elastocap.tracking.depth_weights`):
# each camera's pixels take the depth of the nearest view it held on the previous frame
# (within DEPTH_WEIGHTS_REACH pixels), and a view whose template holds pixels more than
# DEPTH_WEIGHTS_TOLERANCE pixel equivalents nearer or farther than its point is matched with
# them weighed zero (views grouped by depth in bins of DEPTH_WEIGHTS_BIN times the
# tolerance, one Rust call per bin). With DEPTH_WEIGHTS_RESEARCH the second search
# (RESEARCH) does the same. Off: on tuning capture m0 (benches/README.md, branch track16)
# it does not lower the fast limbs' hazard (first / later step 0.419 / 0.093 -> 0.444 /
# 0.102 with tolerance 10, no band) and costs "through" (35.07 -> 33.61%; with a 3 px band
# 28.94%), for fewer kept positions beyond 5 px (3-D 1.45 -> 1.30%) and +40% CPU; beside
# the second search it costs the kept 3-D figure on m2 (2.35 -> 2.54%).
DEPTH_WEIGHTS = False
DEPTH_WEIGHTS_TOLERANCE = 6.0
DEPTH_WEIGHTS_REACH = 12.0
DEPTH_WEIGHTS_BIN = 0.5
# Half-width, pixels, of a band along the depth edges weighed zero for every view near one
# (the labelling puts an edge half-way between two views; 0: no band).
DEPTH_WEIGHTS_BAND = 0
# The forward-backward check's template (the current frame's) cut too, at the depth edges
# of the points moved on linearly (False: by the masks alone).
DEPTH_WEIGHTS_CURRENT = True
DEPTH_WEIGHTS_RESEARCH = True
# The step's box search (which finds the match's start) weighs the template by the same
# per-pixel weights the match gets (the masks, and with DEPTH_WEIGHTS the depth-edge cuts;
# rust/track/weighted_ncc.rs): a template straddling a limb's edge is otherwise refused, or
# started on the surface behind, before the weighted match can act (benches/README.md,
# branch track16). Templates whose weights are all 1 are searched as before, to the bit.
# False: main's plain box search. Off (benches/README.md, branch track19): with the truth's
# box and part labels it finds 3% more of the fast limbs' lost views beyond the weighted
# match; beside DEPTH_WEIGHTS on tuning m0 / m2 / m3 it moves through by -0.10 / -0.23 /
# -0.17 points and leaves the fast limbs' first-step hazard unchanged (the prediction, not
# the patch, loses that step); held out (m16 / m17, DW + this against main) through -1.06 /
# -0.09, kept 3-D beyond 5 px-eq +0.14 / -0.36 points.
WEIGHTED_BOX = False
# The frame-to-frame failures a view's anchor may rescue.
RESCUED = (TrackFlag.LOW_CORRELATION, TrackFlag.FORWARD_BACKWARD, TrackFlag.MATCH_FAILED)
# The step's box centred where the neighbourhood's rigid 3-D motion (rotation included)
# carries each view (tracking/rigid_prediction.py), instead of the linear prediction, for
# the views named by RIGID_PREDICTION: "new" (views with no position on the frame before:
# new seeds, whose linear prediction is no motion at all, and views re-acquired in a
# camera) or "all". None: main's linear prediction. Neighbours: the RIGID_PREDICTION_NEIGHBOURS
# points tracked on both last frames nearest to the point within RIGID_PREDICTION_REACH
# pixels-equivalent at its depth, at least RIGID_PREDICTION_MIN_NEIGHBOURS of them.
# On for new views (benches/README.md, branch track21 and "Session 21, lead"): on the tracks
# of tuning m0 / m2 / m3 the fast limbs' lost new views are in the box's 6 px radius 4-12%
# of the time at the linear prediction and 27-28% at this one (reach 60), and the old
# views' linear prediction is the better ("all" costs m2's fast limbs their later steps).
# "new" against the linear prediction: through +0.0 to +3.9 points on the seven tuning
# seeds and +0.95 / +0.81 held out (m20 / m21); through with RMS <= 0.5 px and kept 3-D
# beyond 5 px-eq move by at most 0.1 point either way (m3 -0.10, m17 -0.01; kept 3-D +0.01
# to +0.03 on four tuning seeds, -0.08 / +0.02 held out). None: the linear prediction.
RIGID_PREDICTION: str | None = "new"
RIGID_PREDICTION_NEIGHBOURS = 8
RIGID_PREDICTION_MIN_NEIGHBOURS = 4
RIGID_PREDICTION_REACH = 60.0
# A young view's lost first step searched coarse to fine (:mod:`elastocap.tracking.pyramid_search`):
# the views with no position on the frame before that the step (and the second search) lost
# to a failed match are searched by the same step on both images reduced PYRAMID_LEVEL times
# (cv2.pyrDown): the box search's correlation in a box of PYRAMID_RADIUS coarse pixels (15 at
# level 2: 60 px) with a template of PYRAMID_SIZE coarse pixels, its peak at least
# PYRAMID_CORRELATION; then the step at full resolution from that peak with the tracker's
# box and checks. The coarse find is kept only if every other local maximum of its
# correlation surface farther than PYRAMID_PEAK_EXCLUSION coarse pixels is at least
# PYRAMID_PEAK_MARGIN lower (a repeated print, the other leg). The coarse correlations are
# first averaged, shift by shift, over the searched views of the point's PYRAMID_POOL
# nearest points in 3-D within PYRAMID_POOL_REACH pixel equivalents (a limb moves together;
# 1: each view's own). On tuning fit seed 14's frames 1-5 (3,190 such views) the pooling,
# margin and correlation cut the finds the intersection keeps more than 5 px from the truth
# from 96 of 435 (no guard) to 12 of 258. False: the step as before session 26.
# On by default since session 26 (benches/README.md, "seedpyr1:" and "Session 26, lead" item 4):
# the elastic fit's drift ratio with tracks, tuning seeds 1 / 10 / 14 / 15 / 18 / 25 / 35 / 42,
# 0.464 / 0.523 / 0.538 / 0.351 / 0.452 / 0.468 / 0.473 / 0.450 -> 0.451 / 0.475 / 0.506 / 0.319 /
# 0.477 / 0.444 / 0.410 / 0.449 (mean 0.465 -> 0.441), held out 46 / 47 0.4625 / 0.4348 -> 0.4629 / 0.4255, no
# frame lost; the tracking figures within 0.25 point of the step without it (m15, m40, m44, m45).
PYRAMID_SEARCH = True
PYRAMID_LEVEL = 2
PYRAMID_RADIUS = 15
PYRAMID_SIZE = 7
PYRAMID_CORRELATION = 0.7
PYRAMID_PEAK_EXCLUSION = 2.0
PYRAMID_PEAK_MARGIN = 0.03
PYRAMID_POOL = 8
PYRAMID_POOL_REACH = 30.0

# A seed's depth search along its partner's epipolar line (tracking/seeding.py): the best
# correlation must beat every other local maximum of the line's correlation by 0.1, the
# maxima within 3 depth samples of the best counting as its own peak. The 96 samples span the
# ray's run through the visual hull; in the nearest partner (a stereo pair's short
# baseline) that run is ~9 px long, so 3 samples are ~0.3 px, and the bilinear sampling's
# kinks at pixel crossings make a second maximum ~0.7 px from the best, ~0.01 lower, with a
# dip of ~0.005 between: the same peak. On big0's frame 5 that refuses 69-83% of the seeds
# whose peak reaches 0.75 (benches/README.md, "seedframe1"). A number: the maxima within
# this many pixels of the partner's image from the best count as its own peak instead.
# None: the 3 samples (unchanged; the option is off pending the tracking and fit figures).
SEED_PEAK_PIXELS: float | None = None

# The window (pixels, odd) with which a seed's other views are matched again from its pixel
# on the epipolar line (tracking.seed_check.rematch_depth); 0: off. The tracker's window on a
# limb puts the seed's depth behind the surface (drift15: median 2.6 px-eq on fit seed 51's
# late seeds, a quarter of them beyond 5).
SEED_DEPTH_SIZE = 0
# New points that hold no narrow stereo pair (two cameras each other's nearest by the angle
# of their axes) are dropped as they are seeded (tracking/seed_pairs.py): their depth was
# matched across a wide baseline, or their pair's view was the intersection's blunder.
# False: kept (main's tracks before session 33). Tuning captures m15 / m68 (alone,
# benches/log/139-kept2.md): kept 3-D beyond 5 px-eq 1.519 / 0.722% -> 1.397 / 0.598%,
# through +0.05 / +0.05 point, 2 / 13 seeds fewer.
SEED_NEEDS_PAIR = True
