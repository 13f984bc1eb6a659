"""Multigrid over the 4-8 levels vs the paper's Jacobi sweeps vs Jacobi-preconditioned CG, on the stiff
approximate-implicit system (M + h^2 L) dv = rhs (multilevel/multigrid.py).

    python benchmarks/multigrid_solver.py [--out out/bench] [--arch cpu|gpu] [--jacobi 300]

Problem (the issue's stiff case): a 1 m square, 4-8 base (16, 16), 7 levels (finest 129 x 129 = 16641
particles), 0.2 kg/m^2 area-lumped, k = 2000 N/m on every triangle edge, h = 1/120 s (h^2 k / m ~ 1.7e4 at
the finest level). Right-hand sides: free fall rhs_i = h m_i g (the worst case for Jacobi: the solution is
the smoothest mode there is) and a random rhs (standard normal, seed 0); unpinned, with the top edge
(y = +0.5 m) pinned, and with only its two ends pinned (point pins: the hanging-cloth scene).

Methods, all on the same matrix, from dv = 0:
  * Jacobi: the paper's smoother (omega = 1, the sweeps of approx_implicit.py), up to --jacobi sweeps;
  * MG V(2,2): plain V-cycles (krylov=False; weighted Jacobi omega = 0.9, exact coarsest solve), float32
    and float64; also V(1,1), and V(2,2) with 50 Jacobi sweeps instead of the exact coarse solve;
  * MG-PCG: CG preconditioned by one V(2,2) cycle per iteration (the solver's default, krylov=True);
  * Jacobi-PCG: CG with the diagonal preconditioner, implemented here in Taichi on the solver's packed
    operator (3 kernel launches per iteration, scalars on the device), float32 and float64.
Reported: iterations/cycles to reach relative residual 1e-3 and 1e-6 (||rhs - A dv|| / ||rhs|| over the free
rows, computed in the solver's precision), the wall time of a solve to that point (median of 7 after a
warm-up, ti.sync(); the machine is shared, expect +-50 % noise), and at that point the error against scipy
spsolve (float64): relative L2 and, for the fall cases, the free-fall velocity fraction mean(dv_y) / (h g)
(1 = free fall). "-" = not reached; then the first column says where the residual stopped and the error
columns show the error there. In float32 the residual has a floor of about eps_f32 * cond(diag(A)^-1 A)
* (how smooth dv is): ~1e-3 on the fall rhs, ~3e-6 on the random one, whatever the method; judge float32
by the error columns.
Work unit (plot): one fine-level operator application (a Jacobi sweep or a CG iteration ~ 1; a V(2,2) cycle
~ 2 x 5.5 since the 4-8 levels halve the particle count per level, + 2 for the CG wrapper).
Also measured (float64 numpy/scipy V-cycles): the Jacobi weight omega, and the rediscretised coarse operators
against Galerkin P^T A P.
Writes multigrid_solver.md (and multigrid_residual.png if matplotlib is importable) into --out.
"""
import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import taichi as ti  # noqa: E402

import taichi_cloth as tc  # noqa: E402
from multilevel.hierarchy import Hierarchy48  # noqa: E402
from multilevel.multigrid import MultigridSolver, edge_operator, prolongation_matrix  # noqa: E402

G = 9.81
H = 1.0 / 120.0
THRESHOLDS = (1e-3, 1e-6)


# ---------------------------------------------------------------------------------------------- problem
PIN_LABELS = {"none": "unpinned", "top": "top edge pinned", "corners": "two top corners pinned"}


def build(pins: str):
    """The hierarchy and one operator per level; pins: "none", "top" (the edge y = +0.5 m) or "corners"
    (its two ends: point pins, the hanging-cloth scene)."""
    hier = Hierarchy48.rectangle((1.0, 1.0), (16, 16), 7)
    ops = []
    for lv in hier.levels:
        top = np.isclose(lv.uv[:, 1], 0.5)
        mask = {"none": None, "top": top, "corners": top & np.isclose(np.abs(lv.uv[:, 0]), 0.5)}[pins]
        ops.append(edge_operator(lv, 0.2, 2000.0, mask))
    return hier, ops


def right_hand_sides(op):
    fall = np.zeros((op.n, 3))
    fall[:, 1] = -H * G * op.mass
    rnd = np.random.default_rng(0).standard_normal((op.n, 3))
    return {"fall": fall, "random": rnd}


# ---------------------------------------------------------------------------------------------- Jacobi-PCG in Taichi
@ti.data_oriented
class JacobiPCG:
    """CG with the diagonal preconditioner on the active level of a MultigridSolver's packed operator
    (reads its mass, ksum, pin and CSR fields). Scalars stay on the device: 3 launches per iteration."""

    def __init__(self, mg):
        self.mg, self.fp = mg, mg.fp
        n = mg.sizes[mg.n_levels - 1]
        self.x = ti.Vector.field(3, self.fp, n)
        self.r = ti.Vector.field(3, self.fp, n)
        self.z = ti.Vector.field(3, self.fp, n)
        self.p = ti.Vector.field(3, self.fp, n)
        self.q = ti.Vector.field(3, self.fp, n)
        self.s = ti.field(ti.f64, 5)  # rz, pq, rz_new, rr, bb

    @ti.func
    def _A(self, v: ti.template(), i, off, hh):
        mg = self.mg
        g = off + i
        acc = ti.Vector.zero(self.fp, 3)
        for e in range(mg.row_ptr[g], mg.row_ptr[g + 1]):
            acc += mg.adj_k[e] * (v[i] - v[mg.adj_j[e] - off])
        return mg.mass[g] * v[i] + hh * acc

    @ti.kernel
    def start(self, rhs: ti.template(), off: ti.i32, n: ti.i32, h: ti.f64):
        mg, hh = self.mg, ti.cast(h * h, self.fp)
        for k in range(5):
            self.s[k] = 0.0
        for i in range(n):
            self.x[i] = ti.Vector.zero(self.fp, 3)
            r = ti.Vector.zero(self.fp, 3)
            if mg.pin[off + i] == 0:
                r = ti.cast(rhs[i], self.fp)
            z = r / (mg.mass[off + i] + hh * mg.ksum[off + i])
            self.r[i], self.z[i], self.p[i] = r, z, z
            self.s[0] += ti.cast(r.dot(z), ti.f64)
            self.s[3] += ti.cast(r.dot(r), ti.f64)
            self.s[4] += ti.cast(r.dot(r), ti.f64)

    @ti.kernel
    def iterate(self, off: ti.i32, n: ti.i32, h: ti.f64):
        mg, hh = self.mg, ti.cast(h * h, self.fp)
        self.s[1] = 0.0
        for i in range(n):
            q = ti.Vector.zero(self.fp, 3)
            if mg.pin[off + i] == 0:
                q = self._A(self.p, i, off, hh)
            self.q[i] = q
            self.s[1] += ti.cast(self.p[i].dot(q), ti.f64)
        self.s[2] = 0.0
        self.s[3] = 0.0
        for i in range(n):
            alpha = ti.cast(self.s[0] / self.s[1], self.fp)
            self.x[i] += alpha * self.p[i]
            r = self.r[i] - alpha * self.q[i]
            z = r / (mg.mass[off + i] + hh * mg.ksum[off + i])
            self.r[i], self.z[i] = r, z
            self.s[2] += ti.cast(r.dot(z), ti.f64)
            self.s[3] += ti.cast(r.dot(r), ti.f64)
        for i in range(n):
            beta = ti.cast(self.s[2] / self.s[0], self.fp)
            self.p[i] = self.z[i] + beta * self.p[i]
        self.s[0] = self.s[2]

    @ti.kernel
    def copy_out(self, dv: ti.template(), n: ti.i32):
        for i in range(n):
            dv[i] = ti.cast(self.x[i], dv.dtype)


# ---------------------------------------------------------------------------------------------- runners
class Runner:
    """One method on one rhs. `reset()` sets dv = 0, `advance(k)` runs k iterations: continuing from the
    current dv if `incremental`, else (MG-PCG: a CG run is not resumable) k iterations from dv = 0."""

    def __init__(self, label, unit_work, reset, advance, residual, state, max_iter, incremental=True):
        self.label, self.unit_work, self.max_iter, self.incremental = label, unit_work, max_iter, incremental
        self.reset, self.advance, self.residual, self.state = reset, advance, residual, state


def make_runners(methods, rhs_np, h, n, jacobi_max):
    """Runners for every (label, kind, solver) method on the rhs rhs_np ((n, 3) float64)."""
    runners = []
    for label, kind, mg in methods:
        rhs, dv = mg._bench_rhs, mg._bench_dv
        rhs.from_numpy(rhs_np.astype(np.float32 if mg.fp == ti.f32 else np.float64))

        def reset(dv=dv):
            dv.fill(0)

        def residual(mg=mg, rhs=rhs, dv=dv):
            return mg.residual_norm(rhs, dv, h)

        def state(dv=dv):
            return dv.to_numpy()[:n].astype(np.float64)

        if kind == "jacobi":
            runners.append(Runner(label, 1.0, reset, lambda k, mg=mg, rhs=rhs, dv=dv: mg.jacobi(rhs, dv, h, k),
                                  residual, state, jacobi_max))
        elif kind == "jpcg":
            pcg, off = mg._bench_pcg, int(mg.offsets[mg.active])

            def reset_pcg(pcg=pcg, rhs=rhs, off=off):
                pcg.start(rhs, off, n, h)

            def adv(k, pcg=pcg, off=off):
                for _ in range(k):
                    pcg.iterate(off, n, h)

            def state_pcg(pcg=pcg, dv=dv):
                pcg.copy_out(dv, n)
                return dv.to_numpy()[:n].astype(np.float64)

            def res_pcg(pcg=pcg, mg=mg, rhs=rhs, dv=dv):  # the true residual, as for the other methods
                pcg.copy_out(dv, n)
                return mg.residual_norm(rhs, dv, h)

            runners.append(Runner(label, 1.0, reset_pcg, adv, res_pcg, state_pcg, 3000))
        else:
            krylov = kind == "mgpcg"

            def adv_mg(k, mg=mg, rhs=rhs, dv=dv, krylov=krylov):
                mg.krylov = krylov
                mg.solve(rhs, dv, h, k)

            runners.append(Runner(label, mg._bench_work + (2.0 if krylov else 0.0), reset, adv_mg, residual, state,
                                  25 if krylov else 40, incremental=not krylov))
    return runners


def history(run: Runner, stop=1e-7):
    """Residual after 0..max_iter iterations. Stops early below `stop`, or below 1e-3 once the best residual
    has not improved 2x over the last `patience` iterations (the float32 floor; CG residuals are not monotone)."""
    patience = min(100, max(8, run.max_iter // 4))
    run.reset()
    res = [run.residual()]
    for k in range(1, run.max_iter + 1):
        if run.incremental:
            run.advance(1)
        else:
            run.reset()
            run.advance(k)
        res.append(run.residual())
        if res[-1] < stop or (len(res) > patience + 1 and min(res) < 1e-3
                              and min(res[-patience:]) > 0.5 * min(res[:-patience])):
            break
    return np.array(res)


def timed(run: Runner, k: int, repeats: int = 7) -> float:
    """Median wall time [ms] of reset + k iterations (after one warm-up)."""
    out = []
    for rep in range(repeats + 1):
        ti.sync()
        t0 = time.perf_counter()
        run.reset()
        run.advance(k)
        ti.sync()
        if rep:
            out.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(out)


# ---------------------------------------------------------------------------------------------- numpy V-cycle: Galerkin vs rediscretised
def numpy_vcycle_factor(hier, ops, h, mode="rediscretised", omega=0.9, nu=2, cycles=8):
    """Average residual reduction per V(nu,nu) cycle (float64 scipy). Coarse operators: "rediscretised" (each
    level's own springs, masses and pins, as MultigridSolver does for these nested pins), "galerkin-pinned"
    (P^T A_f P, coarse levels keep their pins) or "galerkin" (P_F^T A_f P_F with P_F = P with the fine pinned
    rows zeroed: the coarse levels have no pins of their own and see the fine pins through P_F only)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    nl = len(ops)
    free = [~op.pinned if (mode != "galerkin" or lv == nl - 1) else np.ones(op.n, bool) for lv, op in enumerate(ops)]
    Ps = [None] + [prolongation_matrix(hier[l], ops[l - 1].n) for l in range(1, nl)]
    A = [None] * nl
    A[-1] = ops[-1].matrix(h)
    for l in range(nl - 2, -1, -1):
        if mode != "rediscretised":
            P = sp.diags(free[l + 1].astype(float)) @ Ps[l + 1] @ sp.diags(free[l].astype(float))
            A[l] = (P.T @ A[l + 1] @ P).tocsr()
        else:
            A[l] = ops[l].matrix(h)
    F = [sp.diags(f.astype(float)) for f in free]
    A = [(F[l] @ A[l] @ F[l] + sp.diags((~free[l]).astype(float))).tocsr() for l in range(nl)]
    coarse = splu(A[0].tocsc())
    diag = [a.diagonal() for a in A]

    def vcycle(l, b, x):
        if l == 0:
            return coarse.solve(b)
        for _ in range(nu):
            x = x + omega * (b - A[l] @ x) / diag[l]
        r = free[l] * (b - A[l] @ x)
        xc = vcycle(l - 1, free[l - 1] * (Ps[l].T @ r), np.zeros(ops[l - 1].n))
        x = x + free[l] * (Ps[l] @ xc)
        for _ in range(nu):
            x = x + omega * (b - A[l] @ x) / diag[l]
        return x

    b = free[-1] * np.random.default_rng(1).standard_normal(ops[-1].n)
    x = np.zeros_like(b)
    res = [1.0]
    for _ in range(cycles):
        x = vcycle(nl - 1, b, x)
        res.append(np.linalg.norm(free[-1] * (b - A[-1] @ x)) / np.linalg.norm(b))
    return (res[-1] / res[2]) ** (1 / (cycles - 2))


def galerkin_difference(hier, ops, h):
    """||A_c - P^T A_f P||_F / ||A_c||_F per coarse level (unpinned, one level apart), and the Rayleigh quotient
    ratio of the two on the smooth vector u = sin(pi x) sin(pi y) (1 = same energy)."""
    out = []
    for l in range(len(ops) - 1):
        P = prolongation_matrix(hier[l + 1], ops[l].n)
        Ag = (P.T @ ops[l + 1].matrix(h) @ P).tocsr()
        Ar = ops[l].matrix(h)
        fro = np.sqrt(((Ag - Ar).multiply(Ag - Ar)).sum() / Ar.multiply(Ar).sum())
        x, y = hier[l].uv[:, 0], hier[l].uv[:, 1]
        u = np.sin(np.pi * (x + 0.5)) * np.sin(np.pi * (y + 0.5))
        Lr, Lg = ops[l].laplacian(), (P.T @ ops[l + 1].laplacian() @ P)
        out.append((l, fro, float(u @ (Lg @ u)) / float(u @ (Lr @ u))))
    return out


# ---------------------------------------------------------------------------------------------- main
def first_below(res, thr):
    idx = np.nonzero(res <= thr)[0]
    return int(idx[0]) if len(idx) else None


def main():
    p = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    p.add_argument("--out", default="out/bench")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    p.add_argument("--jacobi", type=int, default=300, help="most Jacobi sweeps to run")
    args = p.parse_args()
    tc.init(args.arch)
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [f"# Multigrid solver benchmark ({args.arch}; 1 m square, base (16,16), 7 levels, 129x129 finest, "
             f"0.2 kg/m^2, k = 2000 N/m, h = 1/120 s)", ""]

    def emit(s=""):
        print(s, flush=True)
        lines.append(s)

    curves = {}
    hier, ops = build("none")
    n = ops[-1].n
    t0 = time.perf_counter()

    def solver(fp, **kw):
        mg = MultigridSolver(hier.levels, ops, fp=fp, **kw)
        mg._bench_rhs = ti.Vector.field(3, fp, n)
        mg._bench_dv = ti.Vector.field(3, fp, n)
        mg._bench_pcg = JacobiPCG(mg)
        nu = mg.pre_sweeps + mg.post_sweeps
        # work of one cycle in fine-level operator applications: nu sweeps + residual + transfers per level
        # (the coarse dense solve: 2 n0^2 multiply-adds against ~7 n per fine operator application)
        mg._bench_work = sum((s / n) * (nu + 1.5) for s in mg.sizes[1:]) + \
            (mg.coarse_sweeps * mg.sizes[0] / n if mg.coarse_sweeps else 2 * mg.sizes[0] ** 2 / (7 * n))
        return mg

    f32, f64 = solver(ti.f32), solver(ti.f64)
    v11, cj = solver(ti.f32, pre_sweeps=1, post_sweeps=1), solver(ti.f32, coarse_sweeps=50)
    methods = [("Jacobi (the paper's smoother, omega=1) f32", "jacobi", f32),
               ("MG V(2,2) f32", "mg", f32), ("MG V(2,2) f64", "mg", f64), ("MG V(1,1) f32", "mg", v11),
               ("MG V(2,2), 50 coarse Jacobi sweeps f32", "mg", cj),
               ("MG-PCG V(2,2) f32 (default)", "mgpcg", f32), ("MG-PCG V(2,2) f64", "mgpcg", f64),
               ("Jacobi-PCG f32", "jpcg", f32), ("Jacobi-PCG f64", "jpcg", f64)]
    build_s = time.perf_counter() - t0
    for pins in ("none", "top", "corners"):
        hier, ops = build(pins)
        op = ops[-1]
        for mg in (f32, f64, v11, cj):  # switching the pins compiles nothing
            for lv, o in enumerate(ops):
                mg.set_pinned(lv, o.pinned)
        pin_label = PIN_LABELS[pins]
        emit(f"## {pin_label}  (n = {n}, {int(op.pinned.sum())} pinned; h^2 k / m = "
             f"{H * H * 2000 / np.median(op.mass):.3g}; the 4 solvers were built and compiled in {build_s:.1f} s)")
        for rhs_name, rhs_np in right_hand_sides(op).items():
            exact = op.reference_solve(rhs_np, H)
            emit("")
            emit(f"### {pin_label}, {rhs_name} rhs" + ("  (exact free-fall fraction "
                 f"{exact[~op.pinned, 1].mean() / (-H * G):.4f})" if rhs_name == "fall" else ""))
            emit("| method | work/iter | it to 1e-3 | ms to 1e-3 | rel err @1e-3 | fall frac @1e-3 | it to 1e-6 |"
                 " ms to 1e-6 | rel err @1e-6 | fall frac @1e-6 | ms/iter |")
            emit("|---|---|---|---|---|---|---|---|---|---|---|")
            for run in make_runners(methods, rhs_np, H, n, args.jacobi):
                res = history(run)
                curves[(pin_label, rhs_name, run.label)] = (res, run.unit_work)
                cells = []
                per_iter = timed(run, 10) / 10
                for thr in THRESHOLDS:
                    k = first_below(res, thr)
                    if k is None:
                        cells += ["-", "-", "-", "-"]
                        continue
                    ms = timed(run, k)
                    run.reset()
                    run.advance(k)
                    x = run.state()
                    err = np.linalg.norm(x - exact) / np.linalg.norm(exact)
                    frac = f"{x[~op.pinned, 1].mean() / (-H * G):.4g}" if rhs_name == "fall" else "-"
                    cells += [str(k), f"{ms:.2f}", f"{err:.2e}", frac]
                if first_below(res, THRESHOLDS[0]) is None:  # show where it got to
                    run.reset()
                    run.advance(len(res) - 1)
                    x = run.state()
                    err = np.linalg.norm(x - exact) / np.linalg.norm(exact)
                    frac = f"{x[~op.pinned, 1].mean() / (-H * G):.4g}" if rhs_name == "fall" else "-"
                    cells[0] = f"- (res {res[-1]:.3g} after {len(res) - 1})"
                    cells[2], cells[3] = f"{err:.2e}", frac
                emit(f"| {run.label} | {run.unit_work:.2f} | " + " | ".join(cells) + f" | {per_iter:.3f} |")
            # the paper's step itself: exactly two Jacobi sweeps from 0
            f32._bench_rhs.from_numpy(rhs_np.astype(np.float32))
            f32._bench_dv.fill(0)
            f32.jacobi(f32._bench_rhs, f32._bench_dv, H, 2)
            x = f32._bench_dv.to_numpy()[:n].astype(np.float64)
            res2 = f32.residual_norm(f32._bench_rhs, f32._bench_dv, H)
            frac = f", free-fall fraction {x[~op.pinned, 1].mean() / (-H * G):.3g}" if rhs_name == "fall" else ""
            emit(f"\nPublished form (2 Jacobi sweeps from 0): residual {res2:.3g}, rel err "
                 f"{np.linalg.norm(x - exact) / np.linalg.norm(exact):.3g}{frac}")
        emit("")

    # omega and the coarse operators (float64 numpy/scipy V-cycles)
    emit("## Jacobi weight omega: residual factor per V(2,2) cycle (float64 numpy V-cycle, random rhs)")
    hier, ops = build("none")
    emit("| omega | " + " | ".join(str(w) for w in (0.6, 0.7, 0.8, 0.9, 1.0)) + " |")
    emit("|---|---|---|---|---|---|")
    emit("| factor | " + " | ".join(f"{numpy_vcycle_factor(hier, ops, H, omega=w):.3f}"
                                    for w in (0.6, 0.7, 0.8, 0.9, 1.0)) + " |")
    emit("")
    emit("## Rediscretised vs Galerkin coarse operators (float64 numpy V(2,2), omega 0.9, random rhs)")
    emit("| case | rediscretised (as built) | Galerkin P^T A P, coarse pins kept | Galerkin P_F^T A P_F, no coarse pins |")
    emit("|---|---|---|---|")
    for pins in ("none", "top", "corners"):
        hier, ops = build(pins)
        emit(f"| {PIN_LABELS[pins]} | " + " | ".join(f"{numpy_vcycle_factor(hier, ops, H, m):.3f}" for m in
                                                    ("rediscretised", "galerkin-pinned", "galerkin")) + " |")
    emit("")
    emit("| coarse level | ||A_c - P^T A_f P||_F / ||A_c||_F | smooth-mode energy ratio Galerkin / rediscretised |")
    emit("|---|---|---|")
    hier, ops = build("none")
    for lv, fro, ratio in galerkin_difference(hier, ops, H):
        emit(f"| {lv} | {fro:.3f} | {ratio:.4f} |")

    (out_dir / "multigrid_solver.md").write_text("\n".join(lines) + "\n")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not importable: no plot")
        return
    fig, axes = plt.subplots(3, 2, figsize=(12, 13), sharey=True)
    for ax, (pin_label, rhs_name) in zip(axes.ravel(), [(PIN_LABELS[a], b) for a in ("none", "top", "corners")
                                                         for b in ("fall", "random")]):
        for (pl, rn, label), (res, work) in curves.items():
            if pl == pin_label and rn == rhs_name:
                ax.loglog(1 + np.arange(len(res)) * work, np.maximum(res, 1e-12), label=label)
        ax.set_title(f"{pin_label}, {rhs_name} rhs")
        ax.set_xlabel("1 + work [fine-level operator applications]")
        ax.set_ylabel("||rhs - A dv|| / ||rhs||  (clipped at 1e-12)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_dir / "multigrid_residual.png", dpi=120)
    print(f"wrote {out_dir / 'multigrid_solver.md'} and {out_dir / 'multigrid_residual.png'}")


if __name__ == "__main__":
    main()
