from ctypes import c_double

hduMatrix = (c_double * 4) * 4  # noqa: N816 - the wrapper's names
hduVector3Dd = c_double * 3  # noqa: N816
