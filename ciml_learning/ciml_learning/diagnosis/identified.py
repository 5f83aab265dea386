"""identified_scenario.yaml: what a diagnosis found, as the simulator the logs ask for (docs/DIAGNOSIS.md).

The scenario format is the registry's (ciml_learning/effects/scenario.py), so `ciml record --scenario`
(ciml_sim) loads the file while the diagnosis never imports the simulator.
"""
from __future__ import annotations

import yaml

from ciml_learning.diagnosis.reference import effect_key
from ciml_learning.effects.scenario import outside_range, scenario_effect


def identified_scenario(result: dict, name: str = "identified") -> dict:
    """The simulator a diagnosis asks for (`identified_scenario.yaml`): the identified effects of
    `result` (diagnosis.json: never those at a bound or not identified; sensor effects included).

    With a reference comparison (`--reference`): the reference logs' identified effects plus the
    differences — an effect of the real logs only is added, one that differs takes the real logs'
    value, one of the reference only is left out, a shared one keeps the reference's value. Both are
    identified against the nominal model, so this is the nominal simulator plus what the real logs
    need; the reference's own scenario file is never read. An effect the simulator cannot take (a
    value outside its field's range) is left out and named in the description."""
    effects = list(result.get("effects", []))
    how = "effects identified in the logs against the nominal model"
    comparison = result.get("reference_comparison")
    if comparison is not None:
        real = {effect_key(e): e for e in effects}
        ref = {effect_key(e): e for e in result.get("reference", {}).get("effects", [])}
        status = {(x["type"], x["where"]): x["status"] for x in comparison.get("effects", [])}
        effects = [ref[k] if status.get(k) == "shared" and k in ref else real[k] for k in real]
        how = ("the reference logs' identified effects plus the differences of the real logs (real only: added; "
               "differs: the real value; reference only: left out; shared: the reference's value)")
    entries, left_out = [], []
    for e in effects:
        entry = scenario_effect(e)
        problem = outside_range(entry)
        if problem is None:
            entries.append(entry)
        else:
            left_out.append(problem)
    description = (f"written by ciml diagnose: {how}; no sensor noise (the diagnosis measures a noise floor, "
                   "not the sensors' noise)")
    if left_out:
        description += "; left out: " + "; ".join(left_out)
    return {"name": name, "seed": 0, "sensor_noise": {}, "effects": entries, "description": description}


def identified_scenario_yaml(result: dict) -> str:
    """The YAML text of identified_scenario(result), with a one-line header."""
    header = "# ciml diagnose: the simulator these logs ask for (docs/DIAGNOSIS.md); units SI\n"
    return header + yaml.safe_dump(identified_scenario(result), sort_keys=False, default_flow_style=None)
