"""The kernel cache the mass-spring tests point `SPRINGC_CACHE` at: the run's own
(`$SPRINGC_CACHE` or springc's default, as it is when the suite starts), so that a kernel one
test file compiled is loaded by the next from numba's cache instead of compiled again into a
folder of their own. Their features share it safely: a cache entry is keyed by its clips'
names, sizes and modification times (`springc.kws.features.cache.fingerprint`)."""

from springc.kernels.loader import cache_dir

KERNELS = cache_dir()
