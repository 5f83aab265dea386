#!/usr/bin/env bash
# Regenerates the small committed bags in bags/ with `ciml record` (deterministic: fixed seeds).
#   tools/make_bags.sh            all of them
#   tools/make_bags.sh NAME...    only these
# Each bag: <name> <scenario> <motion> <duration [s]> <seed> <ground truth: gt|nogt>
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
CIML="$ROOT/.venv/bin/ciml"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
BAGS=(
  "nominal_stand    nominal     stand      8 1 nogt"
  "nominal_base     nominal     base_only  6 2 gt"
  "default_gap_base default_gap base_only  6 3 gt"
)
mkdir -p "$ROOT/bags"
for spec in "${BAGS[@]}"; do
  read -r name scenario motion duration seed gt <<<"$spec"
  if (($#)) && [[ ! " $* " =~ " $name " ]]; then continue; fi
  tmp="$ROOT/bags/.$name.new"
  rm -rf "$tmp"
  flag=(); [ "$gt" = nogt ] && flag=(--no-ground-truth)
  echo "[make_bags] $name: $scenario / $motion / ${duration} s / seed $seed ${flag[*]:-}"
  "$CIML" record --scenario "$scenario" --motion "$motion" --duration "$duration" --seed "$seed" \
    "${flag[@]}" --out "$tmp"
  rm -rf "$ROOT/bags/$name"
  mkdir "$ROOT/bags/$name"
  # the bag folder's name is recorded only in the file names: rename them with the folder
  mv "$tmp/.$name.new_0.mcap" "$ROOT/bags/$name/${name}_0.mcap"
  sed "s/\.$name\.new_0\.mcap/${name}_0.mcap/g" "$tmp/metadata.yaml" > "$ROOT/bags/$name/metadata.yaml"
  rm -rf "$tmp"
done
du -sh "$ROOT"/bags/*
