"""m24 with m22's base-wrench models (and the reverse): which dimensions make the spread."""
import sys
from ciml_learning.models import ModelSet, N_BASE
a, b = ModelSet.load(sys.argv[1]), ModelSet.load(sys.argv[2])
for i in range(N_BASE):
    a.models_[i] = b.models_[i]; a.n_samples_[i] = b.n_samples_[i]; a.output_scale_[i] = b.output_scale_[i]
assert (a.input_mean_ == b.input_mean_).all() or True
a.save(sys.argv[3])
print("input scaling equal:", (a.input_mean_ == b.input_mean_).all(), (a.input_scale_ == b.input_scale_).all())
