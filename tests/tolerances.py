"""Every numerical tolerance the Python tests use, in one place.

Each constant says why it has the value it has. Tolerances are either absolute (``*_ATOL``)
or relative to a natural scale named in the comment (``*_RTOL``).
"""

# --- neighbour search -------------------------------------------------------------------

# knn / radius distances vs. cKDTree or brute force: both evaluate sqrt(sum (p - q)^2) in
# double precision, so they differ by a few ulps at most; 1e-12 leaves ~4 decades of room.
DISTANCE_RTOL = 1e-12
# Absolute floor for distances near zero (duplicated points, queries on top of points).
DISTANCE_ATOL = 1e-12

# Two reference distances closer than this (relative) are treated as a tie when deciding
# whether the k nearest index sets must agree exactly; wider than DISTANCE_RTOL so that a
# few-ulp disagreement between implementations never counts as a resolved order.
TIE_RTOL = 1e-9
# Absolute part of the tie test, for ties at distance zero (duplicates).
TIE_ATOL = 1e-12

# Brute-force radius checks on clouds with exact ties: points within this relative band of
# the radius may fall either way (|p - q| <= r vs. |p - q|^2 <= r^2 can disagree by an ulp);
# outside it, membership is strict. The integer-lattice test checks exact inclusion.
RADIUS_BOUNDARY_RTOL = 1e-12

# --- polar decomposition ----------------------------------------------------------------

# R^T R = I, entry-wise: a unit quaternion turned into a matrix is orthonormal to a few ulps.
ORTHONORMAL_ATOL = 1e-12
# det R = +1: same argument as ORTHONORMAL_ATOL.
DETERMINANT_ATOL = 1e-12

# R vs. the SVD rotation U diag(1, 1, det(U V^T)) V^T, entry-wise. A backward-stable method
# errs by about eps * s1 / (s2 + sign(det A) s3); with UNIQUENESS_MARGIN below this is
# <= ~1e-11, so 1e-9 leaves two decades of room.
ROTATION_MATCH_ATOL = 1e-9
# The nearest rotation is treated as unique when s2 + sign(det A) * s3 > this * s1: then its
# condition number is at most ~1 / UNIQUENESS_MARGIN and ROTATION_MATCH_ATOL is attainable.
UNIQUENESS_MARGIN = 1e-5

# Optimality where the rotation is not (safely) unique: tr(R^T A) may fall short of the SVD
# rotation's value by this times s1 (rounding of a 3x3 product: a few ulps of s1).
OPTIMALITY_RTOL = 1e-12

# A == R S with the returned stretch, relative to ||A||_F (det A > 0 only, where the
# factorisation is exact); error ~ eps * condition, bounded as for ROTATION_MATCH_ATOL.
STRETCH_RTOL = 1e-9
# S symmetric: the library symmetrises explicitly, so S - S^T is rounding only (rel. ||A||).
SYMMETRY_RTOL = 1e-14
# S positive semi-definite for det A > 0: smallest eigenvalue >= -this * ||A||_F (a zero
# singular value may come out as a tiny negative number).
PSD_RTOL = 1e-9

# polar(Q A) == Q polar(A) for a rotation Q, entry-wise, where the rotation is unique: both
# sides are accurate to ROTATION_MATCH_ATOL, so this is that tolerance.
EQUIVARIANCE_ATOL = ROTATION_MATCH_ATOL

# --- cameras ----------------------------------------------------------------------------

# Camera.project vs. cv2.projectPoints, in pixels: both evaluate the same polynomial in
# double precision with different operation order; pixels of magnitude ~1e3 carry rounding
# of ~1e-13, so 1e-9 px leaves four decades of room.
PROJECTION_ATOL_PX = 1e-9
# A point projected and cast back lies on its ray: distance to the ray relative to the
# point's distance from the camera centre. Newton's undistortion stops at rounding level
# (~1e-16); 1e-9 leaves room for ill-conditioned (strongly distorted) corners.
RAY_RTOL = 1e-9
# Camera.rays vs. cv2.undistortPoints run to convergence, in normalised image coordinates.
UNDISTORT_ATOL = 1e-12

# --- silhouettes ------------------------------------------------------------------------

# Background subtraction of a synthetic disc on texture + noise: intersection over union
# with the true disc. The boundary ring (~2 pi r pixels, about 4% of a 40-pixel-radius
# disc's area) is where noise and clean-up may err by a pixel; 0.97 allows most of it
# (a 1-pixel Gaussian pre-blur, which widens the mask by a ring, gives 0.95 and fails).
DISC_IOU_MIN = 0.97

# The Middlebury temple's visual hull reprojected into each of its 16 views vs. the view's
# silhouette: issue 3's figure. A one-pixel rim around a silhouette of ~1500 px perimeter
# and ~70000 px area costs about 0.02; calibration error and shadowed parts the rest.
TEMPLE_IOU_MIN = 0.95

# segment_dark_background / refine_silhouette on a synthetic object touching a dim cloth,
# with noise: IoU with the true object. Its boundary ring is ~3% of its area and GrabCut
# may put the cut a pixel off along blurred edges; the threshold alone scores below 0.8.
DARK_SEGMENT_IOU_MIN = 0.95

# --- signed distance --------------------------------------------------------------------

# Distance transforms vs. scipy.ndimage.distance_transform_edt: both are exact (squared
# distances are sums of squared integer multiples of the spacings), so only the final
# sqrt and the half-voxel offset round: 1e-12 relative leaves wide room over 1e-9 asked.
EDT_RTOL = 1e-12
# Trilinear samples vs. scipy.ndimage.map_coordinates(order=1): the same interpolant
# evaluated in a different order of operations; relative to the field's magnitude.
TRILINEAR_RTOL = 1e-12

# --- MLS shape functions ----------------------------------------------------------------

# The SPEC 4.2 identities (partition of unity, linear reproduction, sum grad Phi = 0,
# sum grad Phi x^T = I), entry-wise; gradient sums are made dimensionless by the node's
# support. SPEC asks 1e-10; the core only accepts nodes whose scaled moment matrix has
# rcond >= 1e-3, where the measured error is <= ~1e-13 / rcond, and the test clouds
# (k >= 2D + 2) show ~1e-13.
MLS_IDENTITY_ATOL = 1e-10
# Phi vs. an independent numpy evaluation of the same formula (np.linalg.solve on the
# unscaled moment matrix): both are backward stable on matrices with rcond >~ 1e-2, so
# they agree to ~1e-14; 1e-11 leaves room.
MLS_REFERENCE_ATOL = 1e-11
# grad Phi (times the support, dimensionless) vs. central differences of the numpy Phi(x)
# with step 1e-5 of the support: truncation ~h^2 * |Phi'''| ~ 1e-10 and rounding
# ~eps / h ~ 1e-11; 1e-7 leaves room for the spline's kinks in the third derivative.
MLS_FD_GRADIENT_ATOL = 1e-7

# --- EFG stiffness by nodal integration -------------------------------------------------

# Symmetry of K, entry-wise relative to its largest entry: k_p = V_p B^T (C B) is formed
# with one rounding per product, so the mirror entries differ by ~1e-16 (measured 1e-16).
EFG_SYMMETRY_RTOL = 1e-12
# An eigenvalue counts as zero below this fraction of the largest (SPEC 4.3). The measured
# zero modes sit at ~1e-16 and the smallest non-zero ones at ~4e-5 (2-D, k = 20, 8x8) and
# ~7e-3 (3-D, k = 20, 5^3), so the count does not depend on the threshold over 1e-14..1e-5.
EFG_ZERO_EIGENVALUE_RTOL = 1e-8
# Positive semi-definite: the smallest eigenvalue may be negative by rounding only.
EFG_PSD_RTOL = 1e-12
# Constant-strain patch test (SPEC 4.3): strains of an affine field, absolute, for
# gradients of order 1 (unit grid spacing) and |A| ~ 1; the MLS identities hold to ~1e-13.
EFG_PATCH_ATOL = 1e-9
# K u = 0 for rigid modes, relative to ||K|| ||u|| (as the brief asks).
EFG_RIGID_RTOL = 1e-9
# Energy of a uniform stretch vs 1/2 eps^T C eps times the volume; forces vs -K u.
EFG_ENERGY_RTOL = 1e-9

# --- elastic model ----------------------------------------------------------------------

# Cantilever tip deflection vs. the Timoshenko beam solution, relative: issue 4's bound.
CANTILEVER_RTOL = 0.05
# Rigid motions: energy relative to the energy of a 10% stretch of the same model, and the
# largest force relative to that stretch's largest force. Rounding in F_p, R_p and the
# gathers is ~1e-15 relative; 1e-10 leaves room for poorly conditioned neighbourhoods.
RIGID_RTOL = 1e-10
# Volume kept by the compensated models on the 90-degree bend (issue 4: 2%).
BEND_VOLUME_RTOL = 0.02
# The paper's rhs mode on the same bend: measured 2.4% (it is stiffer to rotation
# increments than the warped mode and compresses the bend slightly); see the issue note.
BEND_VOLUME_RHS_RTOL = 0.03
# The uncompensated model must visibly inflate the bend: measured +30%.
BEND_INFLATION_MIN = 0.10
# --- sparse solvers ---------------------------------------------------------------------

# PCG relative residual asked in the agreement tests: the error is at most the condition
# number times the residual, and the test systems have condition numbers of a few units
# (random, diagonally dominant) up to 2.5e3 (measured: EFG + surface blocks, 2-D 12x12;
# 122 for 3-D 6^3), so 1e-12 keeps the error below SOLVE_AGREEMENT_RTOL (measured ~5e-13);
# it is still ~1e3 above the rounding floor eps * kappa.
SOLVE_CG_TOLERANCE = 1e-12
# PCG and Cholesky vs scipy.sparse.linalg.spsolve, relative 2-norm (issue 4 asks 1e-8).
SOLVE_AGREEMENT_RTOL = 1e-8
# Warm start from spsolve's solution: its residual (~1e-15 relative) already meets the
# tolerance or one step does (issue 4: 0-1 iterations).
SOLVE_WARM_START_ITERATIONS = 1

# --- fitting (SPEC 5) --------------------------------------------------------------------

# Fitted surface nodes vs. the hull they were fitted to: issue 5 asks for 2 voxels (mean).
FIT_HULL_VOXELS = 2.0
# Volume of the fitted surface vs. the rest surface: issue 5's 5%.
FIT_VOLUME_RTOL = 0.05
# A rigidly moved target: elastic energy relative to that of a 5% stretch of the model.
# Measured 1.3-1.9% (warped mode): the surface nodes settle within the target's voxel
# rounding (1/100 of the length), which bends the model a little, the same in every frame.
FIT_RIGID_ENERGY_RTOL = 0.03
# Above twice the rest frame's energy, what a rigidly moved mesh target may add, relative to
# the 5% stretch: the exact signed distance sampled on the target's own 1/100 grid and
# interpolated trilinearly. Measured 0.01-0.1% (warped); accumulating strain (rhs) reaches 36%.
FIT_RIGID_FLOOR_RTOL = 2e-3
# Resumed vs. uninterrupted runs: same start, same arithmetic up to the order of parallel
# sums in the solver, so positions agree to rounding.
FIT_RESUME_RTOL = 1e-9
# Invalidation (two legs, one swung by 75 degrees in one frame): median distance of the
# swung leg's tip nodes to that leg's target, in voxels of the target grid (measured
# 0.05-1.0 over seeds and 600-1000 nodes with invalidation; 4.5-8 voxels without it).
FIT_TIP_ON_LIMB_VOXELS = 2.0
# --- body model (SPEC 6) ----------------------------------------------------------------

# Analytic derivatives vs central differences, per entry relative to |entry| + the row's
# largest entry (the brief asks 1e-6 relative). With step BODY_FD_STEP, truncation is
# ~h^2 |F'''| ~ 1e-12 * (1 / r^3 ~ 1e3) and rounding ~eps / h ~ 1e-10; measured <= 2e-9.
BODY_FD_RTOL = 1e-6
# Central-difference step in metres / radians / coefficient units.
BODY_FD_STEP = 1e-6
# grad F . r at the ray maximum x* (1/m): Newton stops at steps of 1e-10 of the narrowest
# ball's extent, so the slope left is ~|F''| 1e-11 m; measured ~2e-10.
BODY_RAY_STATIONARY_ATOL = 1e-7
# Recovery of a random pose from skin points + silhouettes (the figures).
BODY_ANGLE_RMS_DEG = 1.0
BODY_SHAPE_RTOL = 0.01
# ... with 1 cm point noise and 10% outliers. The shape: max relative error over all
# coefficients, fitted in the generator's own family (depth tied to width, taper held at
# 1: measured 0.022 / 0.019 / 0.015, seeds 1-3, branch body5's exact holding).
BODY_NOISY_ANGLE_RMS_DEG = 3.0
BODY_NOISY_SHAPE_RTOL = 0.03
# ... and with all four coefficients per part free: measured 0.057 / 0.038 / 0.101 (seeds
# 1-3; mean per coefficient 0.7-2.2%): one noisy frame pins 64 coefficients less well than
# the generator's 32 (benches/README.md, branch body4).
BODY_NOISY_SHAPE_4P_RTOL = 0.12
# One-sided stereo's width inflation and its correction by silhouettes: measured against
# the 0.03 bound below before the depth and taper coefficients.
BODY_ONE_SIDED_WIDTH_RTOL = 0.03
# The papers' experiment: one-sided stereo alone inflates the widths by more than this;
# with silhouettes the widths come back within BODY_NOISY_SHAPE_RTOL.
BODY_STEREO_INFLATION_MIN = 0.03

# Two-level PCG (block Jacobi + rigid modes of aggregates) against block Jacobi alone on a
# weakly held elastic body: measured 72 vs 158 iterations (3-D) and 83 vs 158 (2-D) in the
# Rust tests; the Python test asserts at most 60% of block Jacobi's count.
TWO_LEVEL_ITERATION_RATIO = 0.6

# Stabilised 2-D cantilever (consistency penalty 0.1): measured -0.07%, 0.00%, +0.03% of
# Timoshenko at 9, 13, 17 nodes across (plain nodal integration: +4.4%, +2.6%, +1.2%).
CANTILEVER_STABILISED_RTOL = 0.005
# Lowest non-zero stiffness eigenvalue (relative to the largest) of a 250-node capsule:
# measured 9.3e-4 without the penalty and 2.0e-3 with 0.1 (x2.2); asserted x1.5.
STABILIZATION_SOFT_MODE_GAIN = 1.5

# 2-D mask-sequence fit (600 nodes, ellipse 80 x 50 px moving 6.7 px and turning 0.15 rad
# per frame): mean |signed distance| of the contour nodes measured 0.07-0.87 px.
FIT_2D_MEAN_PIXELS = 1.0
# Fitted area over the rest frame's against the masks' pixel-count ratio: measured within
# 2.6% (rigid) and 2.3% (growing by 25%).
FIT_2D_AREA_RTOL = 0.05

# `elastocap body` on a body-model synthetic capture (2 frames, 6 cameras at 320x240,
# silhouettes only, seed 1). Measured: leg joint angles (hip flexion and rotation, knee,
# ankle) within 1.3 degrees; root position within 5 mm; heading within 0.2 degrees; leg,
# head and pelvis coefficients within 3%. The arms (shoulder twist 80 degrees off, widths
# 15-30%) and the root tilt against the hips' side swing (6 degrees) are not determined
# by these silhouettes and are not asserted (benches/README.md, "Body fit on synth").
# The tracker fits silhouettes alone in the narrow family (depth tied to width, taper 1):
# measured legs 0.82 degrees, heading 0.18 degrees, lengths and widths within 0.032 (the
# pelvis's length). With all four coefficients free (branch body4): 3.25 degrees, 1.38
# degrees, 0.077.
BODY_SYNTH_LEG_ANGLE_DEG = 3.0
BODY_SYNTH_ROOT_M = 0.015
BODY_SYNTH_HEADING_DEG = 1.0
BODY_SYNTH_SHAPE_RTOL = 0.05

# --- exports ----------------------------------------------------------------------------

# GLB vertices read back (rest + delta, both float32) against the fit's float64 vertices,
# relative to the mesh's bounding-box diagonal (the bound; float32 rounding of a
# ~2 m figure is ~1e-7 of it).
EXPORT_DIAGONAL_RTOL = 1e-5
# BVH joint positions read by bvhio: offsets and channels are printed with 6 decimals
# (1e-6 m, 1e-6 degree), and 4 to 5 joints chain each rounding.
EXPORT_BVH_ATOL = 2e-5
# .trc positions are printed with 6 decimals (metres).
EXPORT_TRC_ATOL = 1e-6
# .c3d stores float32 points: ~1e-7 relative of positions within a few metres.
EXPORT_C3D_ATOL = 1e-6

# --- distances to triangle meshes ---------------------------------------------------------

# TriangleMesh vs. numpy brute force, relative to the mesh's bounding-box diagonal: both
# compute a point-to-triangle distance in double precision from differences of coordinates
# of size ~1, so they agree to a few ulps of that size (the issue asks for 1e-12).
MESH_DISTANCE_RTOL = 1e-12
# The winding-number reference decides inside / outside only when it is this far from 1/2
# (its solid-angle sums are exact to ~1e-13; points on the surface give 1/2).
WINDING_MARGIN = 1e-6
