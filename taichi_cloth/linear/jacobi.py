"""Block Jacobi: the inverse 3x3 diagonal blocks of the filtered operator S A S + M' (I - S), evaluated inline in
the CG kernels (linear.pcg). On a contact the block is the tangential one, whose inverse is not the per-axis one
(on the T-shirt resting on the body it halved the CG iterations)."""

import taichi as ti

from clothbase.fields import FieldBlock

from .system import filtered_block


@ti.data_oriented
class Jacobi:
    """inv_diag: (P,) 3x3 fields of the model's precision [1/kg], P its particle capacity."""

    inline = True
    in_thread = False  # inline: nothing of its own to run in CG's thread
    #: CG may start from the last step's velocity change (Jacobi is slow to find its smooth part itself)
    warm_start = True
    detail = "block Jacobi"

    def __init__(self, model):
        self.model = model
        blk = FieldBlock()
        self.inv_diag = blk.matrix(3, 3, model.fp, model.capacity[0])
        blk.finalize(self)

    def prepare(self, system, filt) -> None:
        """The block inverses of the system just assembled (linear.BlockSystem, linear.ConstraintFilter)."""
        self._prepare(system, filt)

    def apply(self, r, z) -> None:
        """z = D^-1 r for (P,) vec3 fields r, z."""
        self._apply(r, z)

    @ti.func
    def precondition(self, i, r):
        return self.inv_diag[i] @ r

    @ti.kernel
    def _prepare(self, system: ti.template(), filt: ti.template()):
        m = self.model
        ms = system.mass_scale[None]
        ti.loop_config(serialize=m.serial)
        for i in range(system.gated(m.n_particles[None])):
            if m.inv_mass[i] != 0:
                self.inv_diag[i] = filtered_block(filt.projector(i), system.diagonal(i, ms), m.mass[i] * ms).inverse()

    @ti.kernel
    def _apply(self, r: ti.template(), z: ti.template()):
        for i in range(self.model.n_particles[None]):
            z[i] = self.inv_diag[i] @ r[i]
