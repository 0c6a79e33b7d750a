"""A source patch for mujoco_warp 3.17.0: contacts with an interpolated (trilinear) flex act on the whole body chain.

MuJoCo Warp builds the sparse Jacobian row of such a contact from each contributing body's own dofs
(``for di in range(body_dofnum[b])``), so a contact on a scope link leaves out every joint above that
link (insertion, the hinges up the chain): in the fast stomach a held press reached 7.8 N where MuJoCo
settles at 1.7 N (tests/test_batch.py). C MuJoCo walks the dof tree. This patch makes Warp do the same
in the two kernels that size and fill those rows: it counts and writes every dof on the chain from a
body to the world (``dof_parentid``), which for the stomach's node bodies (children of the world) is
their own three dofs, as before. The kernels are rebuilt from the installed source with three exact
text substitutions; if the installed source differs, :func:`apply` raises instead of guessing.

Off CUDA graphs, Warp's implicit solve (``derivative.eff_solve``) runs all ``opt.iterations`` (1,000) PCG
iterations every step even when every world converged after a few: on Warp's CPU device that was 95 % of a step.
The same substitution mechanism stops the loop once no world is still solving (the skipped iterations leave
``qacc`` untouched).
"""

from __future__ import annotations

import inspect
import linecache
import textwrap

from mjendo.config import ConfigError

# (old, new) text of each kernel factory; every old text must occur exactly once in its factory.
_INIT_FLEX = [(
    "            rownnz += body_dofnum[local_bodies[i]]\n",
    "            chain_dof = body_dofadr[local_bodies[i]] + body_dofnum[local_bodies[i]] - 1\n"
    "            while chain_dof >= 0:\n"
    "              rownnz += 1\n"
    "              chain_dof = dof_parentid[chain_dof]\n",
)]
_JAC_SPARSE_FLEX = [(
    "        dof_start = body_dofadr[b]\n"
    "        ndof = body_dofnum[b]\n"
    "        for di in range(ndof):\n"
    "          dofid = dof_start + di\n",
    "        dofid = body_dofadr[b] + body_dofnum[b] - 1\n"
    "        while dofid >= 0:\n",
), (
    "            Jqvel += J * qvel_in[worldid, dofid]\n"
    "            nnz += 1\n"
    "\n"
    "      efc_Jqvel_out[worldid, efcid] = Jqvel\n",
    "            Jqvel += J * qvel_in[worldid, dofid]\n"
    "            nnz += 1\n"
    "          dofid = dof_parentid[dofid]\n"
    "\n"
    "      efc_Jqvel_out[worldid, efcid] = Jqvel\n",
)]
_EFF_SOLVE = [(
    "      for _ in range(max_it):\n"
    "        _pcg_iteration()\n",
    "      for _ in range(max_it):\n"
    "        _pcg_iteration()\n"
    "        if efm_nsolving.device.is_cpu and efm_nsolving.numpy()[0] == 0:\n"
    "          break\n",
)]
# (module of mujoco_warp._src, function, substitutions, suffix of the rebuilt function's own name)
_PATCHES = [("constraint", "_efc_contact_init_flex", _INIT_FLEX, "_whole_chain"),
            ("constraint", "_efc_contact_jac_sparse_flex", _JAC_SPARSE_FLEX, "_whole_chain"),
            ("derivative", "eff_solve", _EFF_SOLVE, "_until_converged")]  # forward calls derivative.eff_solve
_APPLIED = False
INSTALLED: dict = {}  # mujoco_warp's functions that apply() replaced, as installed (the tests compare with them)


def _patched(module, name: str, subs: list[tuple[str, str]], suffix: str):
    """The factory ``name`` of ``module`` rebuilt from its source with ``subs``, under a new name."""
    src = textwrap.dedent(inspect.getsource(getattr(module, name)))
    for old, new in subs:
        if src.count(old) != 1:
            raise ConfigError(f"mjendo's patch of mujoco_warp's {name} does not fit the installed mujoco_warp "
                              "(it was written for mujoco-warp==3.17.0): install that version with "
                              "`pip install 'mjendo[warp]'`")
        src = src.replace(old, new)
    src = src.replace(f"def {name}(", f"def {name}{suffix}(", 1)  # own name: mujoco_warp caches kernels by name
    filename = f"<mjendo.warp_patch {name}>"
    linecache.cache[filename] = (len(src), None, src.splitlines(keepends=True), filename)  # Warp reads the source
    namespace = module.__dict__
    exec(compile(src, filename, "exec"), namespace)  # noqa: S102 - the installed source, substituted above
    return namespace[name + suffix]


def apply() -> None:
    """Install the patched kernels in mujoco_warp (once per process, before the first step)."""
    global _APPLIED
    if _APPLIED:
        return
    import importlib

    modules = {m: importlib.import_module(f"mujoco_warp._src.{m}") for m, *_ in _PATCHES}
    patched = [(modules[m], name, _patched(modules[m], name, subs, suffix)) for m, name, subs, suffix in _PATCHES]
    for module, name, function in patched:  # only once all fit: a misfit leaves mujoco_warp as installed
        INSTALLED[name] = getattr(module, name)
        setattr(module, name, function)
    _APPLIED = True
