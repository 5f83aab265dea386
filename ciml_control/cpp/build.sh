#!/usr/bin/env bash
# Compiles the controller's C++ core (control_core.cpp) into
# ciml_control/ciml_control/libciml_control_core.so against the headers of the pin and
# proxsuite wheels (and cmeel-eigen) of the given Python (default: python3). ~2.5 min.
# tools/install.sh runs it; with colcon, run it once before `colcon build`.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
PY="${1:-python3}"
OUT="$HERE/../ciml_control/libciml_control_core.so"
CMEEL="$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/cmeel.prefix"
[ -d "$CMEEL/include/eigen3" ] || { echo "no Eigen headers under $CMEEL (pip install cmeel-eigen)" >&2; exit 1; }
# Pinocchio's exported compile definitions; hidden visibility: only the C functions are exported
g++ -O2 -DNDEBUG -std=c++17 -fPIC -shared -fvisibility=hidden -fvisibility-inlines-hidden \
    -DBOOST_MPL_LIMIT_LIST_SIZE=30 -DBOOST_MPL_LIMIT_VECTOR_SIZE=30 -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS \
    -DBOOST_FUSION_INVOKE_MAX_ARITY=12 -I"$CMEEL/include" -I"$CMEEL/include/eigen3" \
    "$HERE/control_core.cpp" -o "$OUT.tmp" \
    -L"$CMEEL/lib" -lboost_serialization -Wl,-rpath,"$CMEEL/lib" -Wl,-Bsymbolic
mv "$OUT.tmp" "$OUT"
