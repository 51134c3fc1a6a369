/*
 * diffusion.h: the voxel diffusion solver of Blanchard 2012 (chapters 2.4, 4.5) as nacre does
 * it (private interface). See solver_setup.c for the discretization, solver.c for the rest.
 *
 * UNITS AND CONVENTIONS
 *   - A medium lives on a dense grid of dims[0] x dims[1] x dims[2] cubic cells of side h (scene
 *     units), index i = x + nx * (y + ny * z). `solid` marks the cells of the domain (the solid
 *     voxelization); the others are outside and keep phi = 0.
 *   - Per channel: sigma_a and the reduced scattering sigma_s' = sigma_s (1 - g) per scene unit;
 *     D = 1 / (3 (sigma_a + sigma_s')).
 *   - Sources are powers per cell (W, the unit of the light's flux), phi is fluence (W per scene
 *     unit squared). The discrete system is the finite-volume balance of each cell:
 *       sum_faces G_f (phi_i - phi_j) + sum_boundary_faces B_f phi_i + sigma_a h^3 phi_i = S_i
 *     with G_f = h D_f, D_f the harmonic mean of the two cells' D (flux continuity), and
 *     B_f = w_f h^2 * 2 D_i / (h + 4 A D_i): the Robin condition phi + 2 A D dphi/dn = 0 of
 *     Arbree et al. (seed eq. 4.7) imposed on the face, half a cell from the centre, w_f the
 *     face's share of true surface area (see staircase_faces; 1 on grid-aligned surfaces).
 *     The matrix is symmetric positive definite.
 *   - Energy: S (injected) = absorbed (sum sigma_a h^3 phi) + escaped (sum B_f phi).
 *   - Periodic axes (slab measurement) wrap around instead of having boundary faces.
 */
#ifndef NACRE_DIFFUSION_H
#define NACRE_DIFFUSION_H

#include "core/core.h"

typedef struct nc_diff_medium {
    uint32_t dims[3];
    float h;                     /* cell side, scene units */
    bool periodic[3];
    const uint8_t *solid;        /* nx*ny*nz, nonzero = in the domain */
    const float *sigma_a[3];     /* per cell and channel; NULL: the constant below */
    const float *sigma_sp[3];    /* reduced scattering per cell and channel; NULL: constant */
    float sigma_a_const[3], sigma_sp_const[3];
    float eta;                   /* relative index of the boundary (one per object) */
    /* Boundary area. A voxelized oblique surface is a staircase with up to sqrt(3) times the
     * area of the surface it stands for, and light escapes through every exposed face. By
     * default (false) each exposed face's Robin term is weighted by |n_face . n|, n the surface
     * normal estimated from the smoothed occupancy around the cell, which gives a planar
     * staircase exactly the area of its plane. true: every exposed face at full area (exact for
     * grid-aligned boxes, whose edges the estimate rounds off). */
    bool staircase_faces;
    /* Per cell, a factor on its boundary weight (NULL: 1): the pipeline's correction for a
     * boundary cell whose centre is not h / 2 below the true surface (pipeline.c, object_setup). */
    const float *boundary_scale;
} nc_diff_medium;

typedef struct nc_diff_solve_opts {
    nacre_diffusion_solver solver;
    float tolerance;             /* MULTIGRID: stop when ||S - M phi|| <= tolerance * ||S|| */
    uint32_t max_iterations;     /* MULTIGRID: PCG iterations cap (0: 200) */
    uint32_t seed_iterations;    /* SEED: Jacobi sweeps at the finest level (0: seed table 5.6) */
    bool seed_single_grid;       /* SEED: no cascade, sweeps on the finest grid only (table 4.3) */
    bool warm_start;             /* phi holds the previous solution on entry */
    bool no_local_relax;         /* warm start: skip the relaxation of the residual's hot spots
                                    (multigrid.c, hot_relax), for comparisons */
    bool no_energy;              /* skip the energy sums of the report (they stay 0): a pass over
                                    the domain that a renderer has no use for */
    bool phi_unchanged;          /* phi holds this solver's last output, untouched since: only
                                    the cells that change are written (the rest are 0 already) */
    uint64_t deadline_us;        /* MULTIGRID: nc_now_us() past which no further PCG iteration
                                    starts (0: none); the report says whether it was reached */
} nc_diff_solve_opts;

typedef struct nc_diff_solve_report {
    uint32_t iterations;         /* PCG iterations or Jacobi sweeps (all levels) */
    double residual;             /* final ||S - M phi|| / ||S|| (0 when S = 0) */
    double injected, absorbed, escaped; /* W, from the final phi */
    bool timed_out;              /* stopped at opts.deadline_us */
} nc_diff_solve_report;

typedef struct nc_diff_solver nc_diff_solver;

nacre_result nc_diff_solver_create(nacre_context *ctx, nc_diff_solver **out);
void nc_diff_solver_destroy(nc_diff_solver *s);
/* Build the operators of all levels and channels for `m` (arrays read, not kept). Buffers are
 * reused when the size does not grow. */
nacre_result nc_diff_setup(nc_diff_solver *s, const nc_diff_medium *m);
/* Solve channel c (0..2) for power `source` (nx*ny*nz, W per cell; outside cells ignored) into
 * `phi` (nx*ny*nz; 0 outside the domain). */
nacre_result nc_diff_solve(nc_diff_solver *s, int channel, const float *source, float *phi,
                           const nc_diff_solve_opts *opts, nc_diff_solve_report *report);
/* All three channels at once (one pass over the grid serves the three: about 3x faster than three
 * nc_diff_solve calls). source[c] / phi[c] as above; a NULL channel is skipped (phi untouched).
 * report may be NULL, else receives one report per channel. */
nacre_result nc_diff_solve_rgb(nc_diff_solver *s, const float *const source[3], float *const phi[3],
                               const nc_diff_solve_opts *opts, nc_diff_solve_report report[3]);
/* D per cell of channel c after setup (nx*ny*nz; 0 outside), for the exitance; NULL with
 * *uniform = D when the medium is homogeneous (then no per-cell array is kept: writing it was
 * 12 bytes per cell of the bounding box per setup, and reading it most of the exitance pass). */
const float *nc_diff_coefficient_d(const nc_diff_solver *s, int channel, float *uniform);

/* The boundary area the Robin terms use after setup: sum over exposed faces of w_f h^2 (scene
 * units squared), the surface through which light escapes. */
double nc_diff_boundary_area(const nc_diff_solver *s);

/* Robin constant A = (1 + Fdr) / (1 - Fdr) for relative index eta (Fdr: nc_fresnel_fdr). */
double nc_diff_robin_a(double eta);
/* Outward flux per unit area through a boundary face of a cell of fluence phi:
 * phi * 2 D / (h + 4 A D) (the Robin condition half a cell from the centre). */
static inline float nc_diff_exitance(float phi, float D, float A, float h)
{
    return phi * 2.0f * D / (h + 4.0f * A * D);
}

/* The diffusion method's slab measurement (nacre_slab_measure with method DIFFUSION; the desc is
 * already checked by src/slab/slab.c). */
nacre_result nc_slab_diffusion(nacre_context *ctx, const nacre_slab_desc *d, nacre_slab_result *out);

#endif /* NACRE_DIFFUSION_H */
