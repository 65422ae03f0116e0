/* Exact box-constrained QPs: min 1/2 z'Hz + g'z subject to lb <= z <= ub, H positive definite
 * (row-major, MPC_NZ x MPC_NZ). The C twins of mpclab.controllers.qp_dense.box_qp_2 and
 * box_qp_active_set: the same method, the same start, the same stopping tests (as multiples
 * of the machine epsilon of mpc_real) and the same iteration cap. Fixed-size buffers on the
 * stack; no dynamic memory. Included by a generated controller, which defines mpc_real,
 * MPC_NZ, MPC_EPS and MPC_FABS before it. */

#define MPC_QP_CONVERGED 0
#define MPC_QP_MAX_ITER 1
#define MPC_QP_NOT_POSITIVE_DEFINITE 2
#ifndef MPC_QP_MAX_ITERATIONS
#define MPC_QP_MAX_ITERATIONS 200 /* box_qp_active_set's max_iter */
#endif

/* 2 variables in closed form (see box_qp_2's docstring for why clipping to a violated bound's
 * edge is exact); h = (h00, h01, h11). */
static void mpc_box_qp_2(const mpc_real h[3], const mpc_real g[2], const mpc_real lb[2],
                         const mpc_real ub[2], mpc_real z[2])
{
    const mpc_real h00 = h[0], h01 = h[1], h11 = h[2];
    const mpc_real det = h00 * h11 - h01 * h01;
    const mpc_real z0 = (h01 * g[1] - h11 * g[0]) / det;
    const mpc_real z1 = (h01 * g[0] - h00 * g[1]) / det;
    const int has_a = z0 < lb[0] || z0 > ub[0], has_b = z1 < lb[1] || z1 > ub[1];
    const mpc_real a = z0 < lb[0] ? lb[0] : ub[0], b = z1 < lb[1] ? lb[1] : ub[1];
    mpc_real e0 = 0, e1 = 0, Ja, Jb;
    if (!has_a && !has_b) {
        z[0] = z0; z[1] = z1;
        return;
    }
    if (has_a) { /* on the edge z0 = a */
        e1 = -(g[1] + h01 * a) / h11;
        e1 = e1 < lb[1] ? lb[1] : (e1 > ub[1] ? ub[1] : e1);
        if (!has_b) { z[0] = a; z[1] = e1; return; }
    }
    if (has_b) { /* on the edge z1 = b */
        e0 = -(g[0] + h01 * b) / h00;
        e0 = e0 < lb[0] ? lb[0] : (e0 > ub[0] ? ub[0] : e0);
        if (!has_a) { z[0] = e0; z[1] = b; return; }
    }
    Ja = (mpc_real)0.5 * (h00 * a * a + h11 * e1 * e1) + h01 * a * e1 + g[0] * a + g[1] * e1;
    Jb = (mpc_real)0.5 * (h00 * e0 * e0 + h11 * b * b) + h01 * e0 * b + g[0] * e0 + g[1] * b;
    if (Ja <= Jb) { z[0] = a; z[1] = e1; } else { z[0] = e0; z[1] = b; }
}

/* Solve H[idx, idx] y = rhs by Cholesky (n <= MPC_NZ); 0 on success. */
static int mpc_chol_solve(int n, const int idx[], const mpc_real *H, const mpc_real rhs[],
                          mpc_real y[])
{
    mpc_real L[MPC_NZ * MPC_NZ];
    int i, j, k;
    for (i = 0; i < n; ++i) {
        for (j = 0; j <= i; ++j) {
            mpc_real s = H[idx[i] * MPC_NZ + idx[j]];
            for (k = 0; k < j; ++k) s -= L[i * MPC_NZ + k] * L[j * MPC_NZ + k];
            if (i == j) {
                if (!(s > 0)) return MPC_QP_NOT_POSITIVE_DEFINITE;
                L[i * MPC_NZ + i] = MPC_SQRT(s);
            } else {
                L[i * MPC_NZ + j] = s / L[j * MPC_NZ + j];
            }
        }
    }
    for (i = 0; i < n; ++i) { /* L w = rhs */
        mpc_real s = rhs[i];
        for (k = 0; k < i; ++k) s -= L[i * MPC_NZ + k] * y[k];
        y[i] = s / L[i * MPC_NZ + i];
    }
    for (i = n - 1; i >= 0; --i) { /* L' y = w */
        mpc_real s = y[i];
        for (k = i + 1; k < n; ++k) s -= L[k * MPC_NZ + i] * y[k];
        y[i] = s / L[i * MPC_NZ + i];
    }
    return MPC_QP_CONVERGED;
}

static mpc_real mpc_max_abs(const mpc_real v[], int n)
{
    mpc_real m = 0;
    int i;
    for (i = 0; i < n; ++i) if (MPC_FABS(v[i]) > m) m = MPC_FABS(v[i]);
    return m;
}

/* Primal active-set method on the bounds from the clipped unconstrained minimizer: solve the
 * equality-constrained problem on the free variables, step to it or to the first bound in the
 * way (which joins the working set); at a zero step release the bound whose multiplier is most
 * negative; stop when none is. Returns MPC_QP_CONVERGED (optimal to the stated tests),
 * MPC_QP_MAX_ITER (z is the last feasible iterate, not optimal) or
 * MPC_QP_NOT_POSITIVE_DEFINITE; *iterations counts the loop's passes. */
static int mpc_box_qp_active_set(const mpc_real *H, const mpc_real g[], const mpc_real lb[],
                                 const mpc_real ub[], mpc_real z[], int *iterations)
{
    int fixed[MPC_NZ], upper[MPC_NZ], idx[MPC_NZ], i, j, it, nf, rc;
    mpc_real p[MPC_NZ], rhs[MPC_NZ], y[MPC_NZ];
    const mpc_real scale = 1 + mpc_max_abs(g, MPC_NZ);
    for (i = 0; i < MPC_NZ; ++i) { idx[i] = i; rhs[i] = -g[i]; }
    rc = mpc_chol_solve(MPC_NZ, idx, H, rhs, z);
    if (rc) { *iterations = 0; return rc; }
    for (i = 0; i < MPC_NZ; ++i) {
        z[i] = z[i] < lb[i] ? lb[i] : (z[i] > ub[i] ? ub[i] : z[i]);
        fixed[i] = z[i] <= lb[i] || z[i] >= ub[i];
        upper[i] = z[i] >= ub[i];
    }
    for (it = 0; it < MPC_QP_MAX_ITERATIONS; ++it) {
        mpc_real alpha = 1;
        int block = -1;
        *iterations = it + 1;
        nf = 0;
        for (i = 0; i < MPC_NZ; ++i) {
            p[i] = 0;
            if (!fixed[i]) idx[nf++] = i;
        }
        if (nf) {
            for (i = 0; i < nf; ++i) {
                mpc_real s = g[idx[i]];
                for (j = 0; j < MPC_NZ; ++j)
                    if (fixed[j]) s += H[idx[i] * MPC_NZ + j] * z[j];
                rhs[i] = -s;
            }
            rc = mpc_chol_solve(nf, idx, H, rhs, y);
            if (rc) return rc;
            for (i = 0; i < nf; ++i) p[idx[i]] = y[i] - z[idx[i]];
        }
        if (mpc_max_abs(p, MPC_NZ) <= MPC_TOL_STEP * (1 + mpc_max_abs(z, MPC_NZ))) {
            mpc_real lam_min = 0;
            int jmin = -1;
            for (i = 0; i < MPC_NZ; ++i) {
                mpc_real grad = g[i], lam;
                if (!fixed[i]) continue;
                for (j = 0; j < MPC_NZ; ++j) grad += H[i * MPC_NZ + j] * z[j];
                lam = upper[i] ? -grad : grad;
                if (jmin < 0 || lam < lam_min) { lam_min = lam; jmin = i; }
            }
            if (jmin < 0 || lam_min >= -MPC_TOL_MULTIPLIER * scale) return MPC_QP_CONVERGED;
            fixed[jmin] = upper[jmin] = 0;
            continue;
        }
        for (i = 0; i < MPC_NZ; ++i) {
            mpc_real a;
            if (fixed[i]) continue;
            if (p[i] < 0) a = (lb[i] - z[i]) / p[i];
            else if (p[i] > 0) a = (ub[i] - z[i]) / p[i];
            else continue;
            if (a < alpha) { alpha = a; block = i; }
        }
        for (i = 0; i < MPC_NZ; ++i) z[i] += alpha * p[i];
        if (block >= 0) {
            z[block] = p[block] < 0 ? lb[block] : ub[block];
            fixed[block] = 1;
            upper[block] = p[block] > 0;
        }
    }
    return MPC_QP_MAX_ITER;
}
