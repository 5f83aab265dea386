"""Research script (results/LIVE_GRAPH.md, thirteenth session): model A with model B's base-wrench
models, to see which dimensions make two models' closed-loop efforts differ.
    python swap_base_models.py MODEL_A MODEL_B OUT_DIR"""
import sys

from ciml_learning.core.physical_bounds import N_BASE
from ciml_learning.learning.models import ModelSet

a, b = ModelSet.load(sys.argv[1]), ModelSet.load(sys.argv[2])
for i in range(N_BASE):
    a.models_[i] = b.models_[i]
    a.n_samples_[i] = b.n_samples_[i]
    a.output_scale_[i] = b.output_scale_[i]
a.save(sys.argv[3])
print("input scaling equal:", bool((a.input_mean_ == b.input_mean_).all()),
      bool((a.input_scale_ == b.input_scale_).all()))
