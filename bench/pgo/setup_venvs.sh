#!/usr/bin/env bash
# Creates the peers' virtual environments under bench/pgo/ (gitignored) if they are missing:
#   .venv-gtsam: PyPI gtsam + numpy
#   .venv-g2o:   PyPI g2o-python + numpy<2 (g2o-python needs numpy 1.x)
set -euo pipefail
cd "$(dirname "$0")"
if [ ! -x .venv-gtsam/bin/python ] || ! .venv-gtsam/bin/python -c "import gtsam, numpy" 2>/dev/null; then
  python3 -m venv .venv-gtsam
  .venv-gtsam/bin/pip install -q gtsam numpy
fi
if [ ! -x .venv-g2o/bin/python ] || ! .venv-g2o/bin/python -c "import g2o, numpy" 2>/dev/null; then
  python3 -m venv .venv-g2o
  .venv-g2o/bin/pip install -q "numpy<2" g2o-python
fi
echo "gtsam $(.venv-gtsam/bin/python -c 'import importlib.metadata as m; print(m.version("gtsam"))'), numpy $(.venv-gtsam/bin/python -c 'import numpy; print(numpy.__version__)')"
echo "g2o-python $(.venv-g2o/bin/python -c 'import importlib.metadata as m; print(m.version("g2o-python"))'), numpy $(.venv-g2o/bin/python -c 'import numpy; print(numpy.__version__)')"
