"""quickhealth: the repository root is the ``quickhealth`` package.

The three folders install as ``quickhealth.identify``, ``quickhealth.vision`` and
``quickhealth.station`` (pyproject.toml maps them; installed, ``quickhealth`` is a namespace
package and this file is not part of it).  It says so to whoever reads the tree: a relative
import such as ``from ..identify.fit import fit_model`` in ``station/`` names the folder beside
it, as it does at run time.
"""
