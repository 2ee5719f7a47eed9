"""The package uses JAX's public API only: no ``jax._src`` anywhere in ``stp_env/`` (JAX's private modules change
without notice), and the public replacements behave as the private functions did: a weakly typed array made from a
host array (``stp_env.execution._weak``), and whether JAX's backends have started (``stp_env.cpu_threads``)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_package_never_names_jax_private_modules():
    pattern = re.compile(r"jax._src")  # as `grep -rn "jax._src" stp_env/` reads it: any character between
    found = [f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
             for path in sorted((ROOT / "stp_env").rglob("*.py"))
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if pattern.search(line)]
    assert not found, "\n".join(found)


@pytest.mark.parametrize("shape", [(), (1,), (3,), (2, 3), (0, 4), (2, 1, 2)])
@pytest.mark.parametrize("dtype", [np.float32, np.int32, np.complex64, np.float16, np.uint8, np.bool_])
def test_weak_gives_the_weak_type_and_keeps_everything_else(shape, dtype):
    import jax
    import jax.numpy as jnp

    from stp_env.execution import _weak

    host = (np.arange(int(np.prod(shape))).reshape(shape) * 3 - 2).astype(dtype)
    value = jnp.asarray(host)
    assert not value.weak_type
    weak = _weak(value)
    assert weak.weak_type and jax.typeof(weak).weak_type
    assert weak.dtype == value.dtype and weak.shape == value.shape
    assert np.asarray(weak).tobytes() == host.tobytes()
    assert weak.committed == value.committed and weak.sharding == value.sharding


@pytest.mark.slow
@pytest.mark.parametrize("scalar", [1.5, -0.0, 7, 2 + 1j])
def test_weak_types_as_jax_types_a_python_scalar(scalar):
    """The same array as JAX makes of a Python scalar (weak, default dtype), and it promotes as one: a weak float
    leaves a float16 array float16."""
    import jax.numpy as jnp

    from stp_env.execution import _weak

    lifted = jnp.asarray(scalar)
    weak = _weak(jnp.asarray(np.asarray(lifted)))
    assert weak.weak_type == lifted.weak_type is True
    assert weak.dtype == lifted.dtype and np.asarray(weak).tobytes() == np.asarray(lifted).tobytes()
    half = jnp.ones(2, jnp.float16)
    assert (weak * half).dtype == (lifted * half).dtype
    for shape in [(3,), (2, 2)]:  # an array of weak type: as jnp.full makes of a Python scalar
        full = jnp.full(shape, scalar)
        weak = _weak(jnp.asarray(np.asarray(full)))
        assert full.weak_type and weak.weak_type and weak.dtype == full.dtype and weak.shape == full.shape


_STARTED = r"""
import json
import jax
from stp_env.cpu_threads import _PROBE_OPTION, _backend_started
before = getattr(jax.config, _PROBE_OPTION)
out = {"imported": _backend_started(), "kept": getattr(jax.config, _PROBE_OPTION) == before}
jax.numpy.ones(2).block_until_ready()
out.update(computed=_backend_started(), kept_after=getattr(jax.config, _PROBE_OPTION) == before)
print(json.dumps(out))
"""


def test_backend_started_answers_through_public_config():
    """Not started after ``import jax``, started after a computation; the option it probes keeps its value."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    out = subprocess.run([sys.executable, "-c", _STARTED], env=env, capture_output=True, text=True, check=True,
                         timeout=300)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == {"imported": False, "kept": True, "computed": True,
                                                                "kept_after": True}
