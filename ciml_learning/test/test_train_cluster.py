"""`ciml train --cluster local:2`: the per-dimension fits on a Dask LocalCluster (127.0.0.1) give the
model that the local run gives (issue 31 item 4)."""
from __future__ import annotations

import os

import numpy as np
import pytest
from synthetic import write_synthetic_bag

from ciml_learning.cli.main import main
from ciml_learning.core.robot import load_robot
from ciml_learning.learning.models import ModelSet

ROBOT = load_robot()


@pytest.mark.slow
def test_train_on_a_local_cluster_equals_the_local_run(tmp_path, capsys):
    bag = str(tmp_path / "synthetic")
    write_synthetic_bag(ROBOT, bag, seconds=3.0, seed=4)
    local, remote = str(tmp_path / "local"), str(tmp_path / "dask")
    assert main(["train", "--bag", bag, "--learner", "lwpr", "--out", local, "--jobs", "1"]) == 0
    assert main(["train", "--bag", bag, "--learner", "lwpr", "--out", remote, "--cluster", "local:2"]) == 0
    assert ModelSet.load(remote, ROBOT).is_fitted()
    arrays = sorted(n for n in os.listdir(local) if n.endswith(".npz"))
    assert arrays and arrays == sorted(n for n in os.listdir(remote) if n.endswith(".npz"))
    for name in arrays:  # every learned array, bit for bit
        with np.load(os.path.join(local, name)) as x, np.load(os.path.join(remote, name)) as y:
            assert sorted(x.files) == sorted(y.files)
            for k in x.files:
                np.testing.assert_array_equal(x[k], y[k])
    assert main(["train", "--bag", bag, "--learner", "lwpr", "--out", str(tmp_path / "x"),
                 "--cluster", "tcp://127.0.0.1:9"]) == 1
    assert "no Dask scheduler answers" in capsys.readouterr().err


@pytest.mark.slow
def test_bags_read_on_processes_or_a_local_cluster_give_the_serial_dataset(tmp_path):
    """pipeline.load_dataset's per-bag reads (cluster.bag_mapper: `--jobs` processes of `ciml diagnose`
    and `ciml train`, or a LocalCluster): the dataset, bag order and counts of the serial read."""
    from ciml_learning.learning.cluster import bag_mapper
    from ciml_learning.logs.pipeline import LOG_COLUMNS, load_dataset

    bags = []
    for seed in (4, 5, 6):
        bags.append(str(tmp_path / f"synthetic{seed}"))
        write_synthetic_bag(ROBOT, bags[-1], seconds=1.5, seed=seed)
    serial = load_dataset(ROBOT, bags, progress=False)
    for mapper in (bag_mapper(2), bag_mapper(cluster="local:2")):
        ds = load_dataset(ROBOT, bags, progress=False, map_bags=mapper)
        assert ds.bags == serial.bags and ds.rejected == serial.rejected and ds.inputs == serial.inputs
        np.testing.assert_array_equal(ds.bag_index, serial.bag_index)
        for name in LOG_COLUMNS:
            np.testing.assert_array_equal(getattr(ds.log, name), getattr(serial.log, name))
        for name, x in vars(serial.targets).items():
            np.testing.assert_array_equal(getattr(ds.targets, name), x)
    assert bag_mapper(1) is None
