"""rvis application layer: configuration, the `rvis` command line, the in-line cycle,
persistence and the operator UI. The only layer that wires devices to algorithms."""

import os

# The numerics multiply small matrices (30 x 30, 3 x 30 blocks) very many times: OpenBLAS's
# thread pool only adds overhead there, and on a busy 2-core machine it stalls (measured 3-8x
# slower planning). rvis parallelises over processes instead. Must be set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
