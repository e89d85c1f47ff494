"""Set-up shared by every test module."""

import numpy  # noqa: F401  (loads numpy's OpenBLAS, so that the limit below reaches it)
import scipy.linalg  # noqa: F401  (loads scipy's own OpenBLAS, likewise)
from threadpoolctl import threadpool_limits

# One BLAS thread in each test process. pytest-xdist already runs one worker per core, and the tests
# that call the fitting code directly (not through the entry points, which run under
# afmsim.reproducible.single_blas_thread) would otherwise give OpenBLAS a second, spinning thread in
# every worker: four threads on two cores. Those tests also get the entry points' bits this way.
# threadpoolctl limits only the libraries already loaded, hence the two imports above: numpy and
# scipy each ship an OpenBLAS of their own.
_ONE_BLAS_THREAD = threadpool_limits(limits=1, user_api="blas")
