/* meshgen.c — deterministic closed triangulated room (see meshgen.h). */
#include "meshgen.h"

#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Reference room size (z up) and the deformation amplitudes. */
#define ROOM_LX 5.0
#define ROOM_LY 4.0
#define ROOM_LZ 3.0
#define WALL_MOVE 0.30  /* x = Lx wall moves out by 30 % of Lx at t = 1 */
#define CEIL_TILT 0.25  /* ceiling height at x = Lx grows by 25 % at t = 1 */

static void seterr(char *err, size_t errlen, const char *fmt, ...) {
    if (!err || errlen == 0) return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
}

/* One wall in lattice coordinates: origin o, unit steps U and W (U x W points inward), and
 * the number of cells along U and W. */
typedef struct Wall { int o[3], U[3], W[3], nu, nw; } Wall;

static void make_walls(int nx, int ny, int nz, Wall w[6]) {
    static const int X[3] = {1, 0, 0}, Y[3] = {0, 1, 0}, Z[3] = {0, 0, 1};
    const int *U[6] = {X, Y, Y, Z, Z, X};
    const int *W[6] = {Y, X, Z, Y, X, Z};
    const int O[6][3] = {{0, 0, 0}, {0, 0, nz}, {0, 0, 0}, {nx, 0, 0}, {0, 0, 0}, {0, ny, 0}};
    const int n[3] = {nx, ny, nz};
    for (int k = 0; k < 6; k++) {
        memcpy(w[k].o, O[k], sizeof O[k]);
        memcpy(w[k].U, U[k], 3 * sizeof(int));
        memcpy(w[k].W, W[k], 3 * sizeof(int));
        w[k].nu = n[U[k] == X ? 0 : U[k] == Y ? 1 : 2];
        w[k].nw = n[W[k] == X ? 0 : W[k] == Y ? 1 : 2];
    }
}

/* Choose the grid: among nx, ny, nz >= 1 with F0 = 4 (nx ny + ny nz + nz nx) <= F <= 2 F0,
 * minimise log(cell aspect ratio) + 2 (F - F0) / F (square cells, few fans). Deterministic. */
static int choose_grid(long F, int *bx, int *by, int *bz) {
    const long q = F / 4;
    double best = INFINITY;
    int found = 0;
    for (long nx = 1; nx <= q; nx++) {
        for (long ny = 1; nx * ny <= q; ny++) {
            for (long nz = 1; nx * ny + (nx + ny) * nz <= q; nz++) {
                long F0 = 4 * (nx * ny + ny * nz + nz * nx);
                if (F > 2 * F0) continue;
                double hx = ROOM_LX / (double)nx, hy = ROOM_LY / (double)ny, hz = ROOM_LZ / (double)nz;
                double hmax = fmax(hx, fmax(hy, hz)), hmin = fmin(hx, fmin(hy, hz));
                double cost = log(hmax / hmin) + 2.0 * (double)(F - F0) / (double)F;
                if (cost < best - 1e-12) {
                    best = cost;
                    *bx = (int)nx, *by = (int)ny, *bz = (int)nz;
                    found = 1;
                }
            }
        }
    }
    return found;
}

static void place(const int lat[3], const int n[3], double t, double out[3]) {
    double x = ROOM_LX * lat[0] / n[0], y = ROOM_LY * lat[1] / n[1], z = ROOM_LZ * lat[2] / n[2];
    out[0] = x * (1.0 + WALL_MOVE * t);
    out[1] = y;
    out[2] = z * (1.0 + CEIL_TILT * t * x / ROOM_LX);
}

int mesh_room(long F, double t, Mesh *out, char *err, size_t errlen) {
    if (!out) {
        seterr(err, errlen, "mesh_room: no output mesh");
        return -1;
    }
    memset(out, 0, sizeof *out);
    if (F < 12 || F % 2 != 0) {
        seterr(err, errlen, "mesh_room: F = %ld faces: need an even number >= 12", F);
        return -1;
    }
    if (F > INT_MAX / 3) {
        seterr(err, errlen, "mesh_room: F = %ld faces is too large", F);
        return -1;
    }
    if (!isfinite(t)) {
        seterr(err, errlen, "mesh_room: deformation t is not finite");
        return -1;
    }
    int nx = 0, ny = 0, nz = 0;
    if (!choose_grid(F, &nx, &ny, &nz)) {
        seterr(err, errlen, "mesh_room: no box grid fits F = %ld faces", F);
        return -1;
    }
    const int n[3] = {nx, ny, nz};
    const long Q0 = 2L * ((long)nx * ny + (long)ny * nz + (long)nz * nx); /* quads */
    const long kfan = (F - 2 * Q0) / 2; /* quads split into 4 triangles instead of 2 */
    const size_t nlat = (size_t)(nx + 1) * (size_t)(ny + 1) * (size_t)(nz + 1);
    const long Vmax = (long)nlat + kfan;

    int *idx = malloc(nlat * sizeof *idx);
    double *g = malloc((size_t)Vmax * 3 * sizeof *g);
    int *tri = malloc((size_t)F * 3 * sizeof *tri);
    if (!idx || !g || !tri) {
        free(idx), free(g), free(tri);
        seterr(err, errlen, "mesh_room: out of memory for F = %ld faces", F);
        return -1;
    }
    for (size_t i = 0; i < nlat; i++) idx[i] = -1;

    Wall walls[6];
    make_walls(nx, ny, nz, walls);
    long V = 0, f = 0, q = 0;
    for (int w = 0; w < 6; w++) {
        const Wall *W = &walls[w];
        for (int b = 0; b < W->nw; b++) {
            for (int a = 0; a < W->nu; a++, q++) {
                /* corners p00, p10, p11, p01 in (u, w) */
                static const int du[4] = {0, 1, 1, 0}, dw[4] = {0, 0, 1, 1};
                int c[4];
                for (int k = 0; k < 4; k++) {
                    int lat[3];
                    for (int d = 0; d < 3; d++)
                        lat[d] = W->o[d] + (a + du[k]) * W->U[d] + (b + dw[k]) * W->W[d];
                    size_t li = ((size_t)lat[0] * (size_t)(ny + 1) + (size_t)lat[1]) * (size_t)(nz + 1) +
                                (size_t)lat[2];
                    if (idx[li] < 0) {
                        idx[li] = (int)V;
                        place(lat, n, t, &g[3 * V]);
                        V++;
                    }
                    c[k] = idx[li];
                }
                int fan = (q + 1) * kfan / Q0 > q * kfan / Q0;
                if (!fan) {
                    int *T = &tri[3 * f];
                    T[0] = c[0], T[1] = c[1], T[2] = c[2];
                    T[3] = c[0], T[4] = c[2], T[5] = c[3];
                    f += 2;
                } else {
                    double *m = &g[3 * V];
                    for (int d = 0; d < 3; d++)
                        m[d] = 0.25 * (g[3 * c[0] + d] + g[3 * c[1] + d] + g[3 * c[2] + d] + g[3 * c[3] + d]);
                    int mc = (int)V++;
                    for (int k = 0; k < 4; k++) {
                        int *T = &tri[3 * f];
                        T[0] = c[k], T[1] = c[(k + 1) % 4], T[2] = mc;
                        f++;
                    }
                }
            }
        }
    }
    free(idx);
    if (f != F) { /* cannot happen: the counts above are exact */
        free(g), free(tri);
        seterr(err, errlen, "mesh_room: internal error: built %ld faces, wanted %ld", f, F);
        return -1;
    }
    double *gs = realloc(g, (size_t)V * 3 * sizeof *g);
    out->V = V;
    out->F = F;
    out->g = gs ? gs : g;
    out->tri = tri;
    return 0;
}

void mesh_free(Mesh *m) {
    if (!m) return;
    free(m->g);
    free(m->tri);
    memset(m, 0, sizeof *m);
}

static void face_normal(const Mesh *m, long f, double nv[3]) {
    const double *p0 = &m->g[3 * m->tri[3 * f]], *p1 = &m->g[3 * m->tri[3 * f + 1]],
                 *p2 = &m->g[3 * m->tri[3 * f + 2]];
    double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
    double e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
    nv[0] = e1[1] * e2[2] - e1[2] * e2[1];
    nv[1] = e1[2] * e2[0] - e1[0] * e2[2];
    nv[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

int mesh_face_wall(const Mesh *m, long f) {
    double nv[3];
    face_normal(m, f, nv);
    int ax = 0;
    for (int d = 1; d < 3; d++)
        if (fabs(nv[d]) > fabs(nv[ax])) ax = d;
    /* inward normals: +z floor, -z ceiling, +x wall x = 0, -x wall x = Lx, +y y = 0, -y y = Ly */
    if (ax == 2) return nv[2] > 0 ? 0 : 1;
    if (ax == 0) return nv[0] > 0 ? 2 : 3;
    return nv[1] > 0 ? 4 : 5;
}

void mesh_rho(const Mesh *m, double *rho) {
    static const double albedo[6] = {0.3, 0.8, 0.5, 0.6, 0.7, 0.55};
    for (long f = 0; f < m->F; f++) rho[f] = albedo[mesh_face_wall(m, f)];
}

long mesh_emission(const Mesh *m, double *e) {
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (long v = 0; v < m->V; v++)
        for (int d = 0; d < 2; d++) {
            lo[d] = fmin(lo[d], m->g[3 * v + d]);
            hi[d] = fmax(hi[d], m->g[3 * v + d]);
        }
    long count = 0, nearest = -1;
    double best = INFINITY;
    for (long f = 0; f < m->F; f++) {
        e[f] = 0.0;
        if (mesh_face_wall(m, f) != 1) continue;
        double u[2];
        for (int d = 0; d < 2; d++) {
            double c = (m->g[3 * m->tri[3 * f] + d] + m->g[3 * m->tri[3 * f + 1] + d] +
                        m->g[3 * m->tri[3 * f + 2] + d]) / 3.0;
            u[d] = (c - lo[d]) / (hi[d] - lo[d]); /* relative position: invariant under t */
        }
        /* margins of 1e-9 so that centroids exactly on a boundary (they occur: lattice
         * coordinates) are decided the same way for every t despite round-off */
        double dist = fabs(u[0] - 0.5) + fabs(u[1] - 0.5);
        if (dist < best - 1e-9) best = dist, nearest = f;
        if (fabs(u[0] - 0.5) < 1.0 / 6.0 - 1e-9 && fabs(u[1] - 0.5) < 1.0 / 6.0 - 1e-9) e[f] = 1.0, count++;
    }
    if (count == 0 && nearest >= 0) e[nearest] = 1.0, count = 1;
    return count;
}
