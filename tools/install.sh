#!/usr/bin/env bash
# Installs everything CIML needs into ./.venv, idempotently:
#   system tools (apt, only when missing) -> venv + pinned wheels -> ciml_msgs (rosidl, CMake)
#   -> side by side: the controller core and the batch core (C++, CMake), and the three ament_python
#      packages (editable, ros2-run layout lib/<pkg>/<exe>) with the learners' numba kernels.
# Each step is skipped when the files it depends on have not changed (hash stamps).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
PY="$VENV/bin/python"
STAMPS="$VENV/.ciml-stamps"
log() { printf '[install] %s\n' "$*"; }

need_apt=()
command -v python3 >/dev/null || need_apt+=(python3)
python3 -c 'import ensurepip, venv' 2>/dev/null || need_apt+=(python3-venv)
command -v cmake >/dev/null || need_apt+=(cmake)
command -v g++ >/dev/null || need_apt+=(g++)
command -v make >/dev/null || need_apt+=(make)
python3 -c 'import sysconfig,os,sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"],"Python.h")))' \
  || need_apt+=(python3-dev)
if ((${#need_apt[@]})); then
  log "installing system packages: ${need_apt[*]}"
  if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
  $SUDO apt-get update -qq && $SUDO apt-get install -y -qq "${need_apt[@]}"
fi

hash_of() { cat "$@" | sha256sum | cut -c1-16; }
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

if [ ! -x "$PY" ]; then
  log "creating venv $VENV"
  python3 -m venv "$VENV"
fi

h=$(hash_of "$ROOT/requirements.txt" "$ROOT/constraints.txt")
if ! stamp_ok wheels "$h"; then
  log "installing pinned wheels (ROS 2 Jazzy, pinocchio, GPy, proxsuite, rosbags, mujoco, ...)"
  "$PY" -m pip install -q --upgrade pip
  "$PY" -m pip install -q -r "$ROOT/requirements.txt" -c "$ROOT/constraints.txt"
  # The message wheels' exported CMake targets name include folders of the machine that
  # built them; point them at this interpreter's and this venv's numpy (docs/ARCHITECTURE.md §10).
  "$PY" "$ROOT/tools/fix_cmake_exports.py" "$VENV"
  stamp_set wheels "$h"
fi

h=$(hash_of "$ROOT"/ciml_msgs/CMakeLists.txt "$ROOT"/ciml_msgs/package.xml "$ROOT"/ciml_msgs/msg/*.msg "$STAMPS/wheels")
if ! stamp_ok msgs "$h"; then
  log "building ciml_msgs (rosidl) into the venv"
  BUILD="$ROOT/build/ciml_msgs"
  rm -rf "$BUILD"; mkdir -p "$BUILD"
  (cd "$BUILD" && \
   CMAKE_PREFIX_PATH="$VENV" AMENT_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH" \
   cmake "$ROOT/ciml_msgs" -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$PY" \
         -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release > cmake.log 2>&1 && \
   CMAKE_PREFIX_PATH="$VENV" AMENT_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH" \
   make -j"$(nproc)" install > make.log 2>&1) || { log "ciml_msgs build failed, see $BUILD/*.log"; tail -n 30 "$BUILD"/*.log; exit 1; }
  stamp_set msgs "$h"
fi

# The two C++ cores (CMake; Pinocchio and proxsuite headers from the cmeel wheels) into their Python
# package folders: the controller's step (ciml_control/cpp, ~2.5 min) and the offline batch core
# (ciml_learning/cpp, ~2 min: extraction's and the diagnosis's per-sample dynamics over batches).
# CMake itself rebuilds only what changed.
CMEEL="$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/cmeel.prefix"
build_core() {  # stamp  source-folder  library  what
  local h; h=$(hash_of "$ROOT/$2"/* "$STAMPS/wheels")
  stamp_ok "$1" "$h" && [ -f "$ROOT/$3" ] && return 0
  log "compiling $4"
  local build="$ROOT/build/$1_core"
  mkdir -p "$build"
  (cmake -S "$ROOT/$2" -B "$build" -DCMAKE_PREFIX_PATH="$CMEEL" -DCMAKE_BUILD_TYPE=Release \
     > "$build/cmake.log" 2>&1 && cmake --build "$build" > "$build/make.log" 2>&1) \
    || { tail -n 30 "$build"/*.log; log "$4 failed, see $build/*.log"; return 1; }
  stamp_set "$1" "$h"
}

install_packages() {
  local h; h=$(hash_of "$ROOT"/ciml_*/setup.py "$ROOT"/ciml_*/setup.cfg "$ROOT"/ciml_*/package.xml "$STAMPS/wheels" \
    $(find "$ROOT"/ciml_learning/config "$ROOT"/ciml_control/config "$ROOT"/ciml_sim/config "$ROOT"/ciml_sim/launch \
      -type f 2>/dev/null | sort))
  if ! stamp_ok pkgs "$h"; then
    log "installing ciml_learning, ciml_control, ciml_sim (editable)"
    mkdir -p "$ROOT/build"
    "$PY" -m pip install -q --no-deps --no-build-isolation \
      -e "$ROOT/ciml_learning" -e "$ROOT/ciml_control" -e "$ROOT/ciml_sim" > "$ROOT/build/pip-editable.log" 2>&1 \
      || { cat "$ROOT/build/pip-editable.log"; return 1; }
    "$PY" "$ROOT/tools/ament_layout.py" "$ROOT" "$VENV" ciml_learning ciml_control ciml_sim || return 1
    stamp_set pkgs "$h"
  fi
  # The learners' numba kernels, compiled once into numba's cache (__pycache__ beside the sources), so that the
  # first live graph's online learner starts at once: compiled on first use they took 144 s beside a running graph
  h=$(hash_of "$ROOT"/ciml_learning/ciml_learning/learning/learners/*.py "$STAMPS/wheels")
  if ! stamp_ok kernels "$h"; then
    log "compiling the learners' kernels (numba cache)"
    "$PY" -c 'from ciml_learning.learning.online import warm_up; from ciml_learning.core.profile import load_profile
warm_up(load_profile("hyq").robot())' || { log "compiling the learners' kernels failed"; return 1; }
    stamp_set kernels "$h"
  fi
}

# The cores and the packages do not depend on each other, and each core is one translation unit (a
# single-threaded build): side by side they take the longest one's time instead of the sum.
pids=()
build_core control ciml_control/cpp ciml_control/ciml_control/libciml_control_core.so \
  "the controller core (C++: Pinocchio, proxsuite)" & pids+=($!)
build_core batch ciml_learning/cpp ciml_learning/ciml_learning/libciml_learning_core.so \
  "the batch dynamics core (C++: Pinocchio)" & pids+=($!)
install_packages & pids+=($!)
failed=0
for pid in "${pids[@]}"; do wait "$pid" || failed=1; done
[ "$failed" = 0 ] || exit 1
log "ready: $VENV"
