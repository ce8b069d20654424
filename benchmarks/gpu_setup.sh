# Sourced on a lent GPU machine from the repository's root (gpu_compare.sh, or before gpu_variants.py): the carried
# wheels installed, softreach importable from this checkout, the interpreter in $PY.
export PYTHONUNBUFFERED=1
PY=${PYTHON:-python3}
# the peer and what the machine lacks (gymnasium, stable-baselines3: the command line imports them), from the carried
# wheels; softreach importable without pip: a softreach package of links to the repo's folders
if ls .whl/*.whl >/dev/null 2>&1; then
  $PY -m pip install -q --upgrade --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl
fi
# numba-cuda 0.30 registers an overload of np.row_stack, which numpy 2.5 removed (an alias of np.vstack;
# NVIDIA/numba-cuda#907): where the machine's numpy lacks it, put the alias back at interpreter start
# (sitecustomize on PYTHONPATH), for these runs only; the machine's torch and JAX need its numpy
mkdir -p /tmp/site
printf 'import numpy\nif not hasattr(numpy, "row_stack"):\n    numpy.row_stack = numpy.vstack\n' >/tmp/site/sitecustomize.py
rm -rf /tmp/sr && mkdir -p /tmp/sr/softreach && cp -r src/softreach/. /tmp/sr/softreach/
for d in reach envs filters agents; do ln -sfn "$PWD/$d" "/tmp/sr/softreach/$d"; done
export PYTHONPATH=/tmp/sr:/tmp/site${PYTHONPATH:+:$PYTHONPATH}
