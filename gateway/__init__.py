"""Serra gateway: ingest → store → model/estimate → virtual sensor → publish.

Our numeric work is many small matrix products (a population times a handful of basis rows);
a multi-threaded BLAS spends more on waking threads than on the work, and on a loaded 2–4 core
gateway it was measured 50× slower. Default to one BLAS thread unless the user chose otherwise.
This must run before numpy is first imported.
"""

import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
