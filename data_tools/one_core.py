"""Imported by a benchmark before numpy or OpenCV: their thread pools kept to one thread, so
that every figure is one core's (the variables count only if set before those libraries load).
"""

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
