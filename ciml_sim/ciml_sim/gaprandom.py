"""`ciml gap-bench --random N --seed S [--cluster ADDRESS]`: the gap-bench on randomly drawn hidden cases.

The cases come from the effect registry's generator (ciml_learning.effects.draws: 0–3 effects, a noise
level, motions and a seed per case; some nominal, some outside the catalogue). Each case runs as a
suite case does (gapbench.run_case: record without ground truth, `ciml diagnose` in its own process on
the bag paths alone, `ciml verify`), then the scorer adds what the statistics need: each true effect's
size and what was named in its place (the confusion matrix). The draw is written with the results
(DIR/draws.json before any case runs, and in gap_bench.json), so `--random N --seed S` is the bench.
Each finished case writes its scores to case_NN/score.json, so an interrupted bench goes on where it
stopped (`--resume`): hundreds of cases outlast a session, a machine or a cluster.

Cases are independent: locally they run on joblib's processes (--jobs), on a cluster as Dask tasks
(--cluster, ciml_learning.learning.cluster); both call random_case() and give the same scores.
"""
from __future__ import annotations

import json
import os
import time

from ciml_learning.core.fileio import atomic_write_json, atomic_write_text

from . import gapbench, gapstats

SCORE_FILE = "score.json"
"""A finished case's scores (with its timings), in its case folder: the mark `--resume` keeps it by."""
CASE_FIELDS = ("seed", "kind", "noise_scale", "sensor_noise", "effects", "train_motions", "heldout_motions")


def draw(n: int, seed: int) -> list[dict]:
    """The N cases of a master seed, on the suite robot's (HyQ's) joints, leg links and motions."""
    from ciml_control.references import MOTIONS
    from ciml_learning.core.robot import load_robot
    from ciml_learning.diagnosis.candidates import link_inertias
    from ciml_learning.effects.draws import draw_cases

    robot = load_robot()
    # the leg links the diagnosis has a candidate for; the root (joint 1) would duplicate a payload
    links = [link.name for link in link_inertias(robot) if link.joint > 1]
    return draw_cases(n, seed, robot.joint_names, links, MOTIONS)


def score_random_case(spec: dict, scored: dict, diagnosis: dict) -> dict:
    """Add to a scored case (gapbench.score_case) the kind, each true effect's size and the confusion
    entries ([true, named] pairs) of its truth against its diagnosis."""
    from ciml_learning.effects.draws import effect_size, size_unit

    found = diagnosis.get("effects", [])
    unexplained = float(diagnosis.get("unexplained_share") or 0.0)
    floor = bool(diagnosis.get("gap_at_noise_floor", False))
    out = dict(scored, kind=spec["kind"])
    in_cat = [e for e in spec["effects"] if e["type"] not in gapbench.OUT_OF_CATALOGUE]
    for row, truth in zip(out["effects"], in_cat):
        row["size"] = effect_size(truth)
        row["size_unit"] = size_unit(truth["type"])
    pairs = [[r["type"], gapstats.named_in_catalogue(r, found, out["spurious"], unexplained)] for r in out["effects"]]
    if spec["kind"] == "nominal":
        out["named"] = gapstats.named_without_catalogue(found, unexplained, floor, gapbench.SPURIOUS_SHARE)
        pairs.append([gapstats.NOMINAL_ROW, out["named"]])
    elif spec["kind"] == "out_of_catalogue":
        true = [e["type"] for e in spec["effects"] if e["type"] in gapbench.OUT_OF_CATALOGUE][0]
        pairs.append([true, gapstats.named_without_catalogue(found, unexplained, floor, gapstats.CONFIDENT_SHARE)])
    out["confusion"] = pairs
    return out


def random_case(job: tuple[int, dict, str, float]) -> dict:
    """Run and score case (index, spec, out_dir, scale) on this machine (a joblib or a Dask worker);
    a failing case is a scored failure, the bench goes on."""
    index, spec, out_dir, scale = job
    try:
        scored = gapbench.run_case(index, spec, out_dir, scale)
        case = os.path.join(out_dir, f"case_{index:02d}")
        with open(os.path.join(case, "diagnosis", "diagnosis.json"), encoding="utf-8") as f:
            diagnosis = json.load(f)
        result = score_random_case(spec, scored, diagnosis)
        atomic_write_json(os.path.join(case, SCORE_FILE), result)
        return result
    except Exception as err:  # recorded in the case's row and counted in failed_cases
        return {"case": index, "kind": spec["kind"], "effects_true": spec["effects"], "error": str(err)}


def finished_cases(out_dir: str, n: int, seed: int) -> dict[int, dict]:
    """The cases an earlier run of the same draw finished in DIR (case → its score.json); a draw of
    another N or seed is a CimlError (its cases are other cases)."""
    from ciml_learning.core.errors import CimlError
    from ciml_learning.core.fileio import InputFileError, load_json_bounded

    path = os.path.join(out_dir, "draws.json")
    if not os.path.isfile(path):
        return {}
    drawn = load_json_bounded(path, "draws.json")
    if (drawn.get("n"), drawn.get("seed")) != (n, seed):
        raise CimlError(f"--resume: {out_dir} holds the draw of --random {drawn.get('n')} --seed {drawn.get('seed')}, "
                        f"not --random {n} --seed {seed}")
    done = {}
    for i in range(1, n + 1):
        score = os.path.join(out_dir, f"case_{i:02d}", SCORE_FILE)
        if os.path.isfile(score):
            try:
                done[i] = load_json_bounded(score, SCORE_FILE)
            except InputFileError:  # unreadable: the case runs again
                continue
    return done


def rescore(out_dir: str) -> dict:
    """Score the diagnoses of a random bench in DIR again (after a change of the scoring), from its
    draws.json and case folders, without recording or diagnosing; keeps the timings and the engine."""
    from ciml_learning.core.fileio import load_json_bounded
    from ciml_learning.core.robot import load_robot

    gapbench._LINKS.update(load_robot().link_names)
    drawn = load_json_bounded(os.path.join(out_dir, "draws.json"), "draws.json")
    old_path = os.path.join(out_dir, "gap_bench.json")
    old = load_json_bounded(old_path, "gap_bench.json") if os.path.isfile(old_path) else {}
    timing = {c["case"]: c for c in old.get("cases", [])}
    results: list[dict | None] = []
    for i, spec in enumerate(drawn["cases"], start=1):
        case = os.path.join(out_dir, f"case_{i:02d}")
        path = os.path.join(case, "diagnosis", "diagnosis.json")
        if not os.path.isfile(path):  # never diagnosed: a failure stays one, a missing case stays missing
            results.append(timing.get(i))
            continue
        diagnosis = load_json_bounded(path, "diagnosis.json")
        scored = gapbench.score_case(spec["effects"], diagnosis, load_robot().joint_names)
        scored.update({k: v for k, v in timing.get(i, {}).items() if k.endswith("_s")})
        scored.update({"case": i, "effects_true": spec["effects"], "noise": bool(spec["sensor_noise"]),
                       **gapbench.resimulated_scores(case)})
        results.append(score_random_case(spec, scored, diagnosis))
    meta = {k: old[k] for k in ("scale", "engine", "wall_s") if k in old}
    return write(out_dir, drawn["n"], drawn["seed"], drawn["cases"], results, meta)


def write(out_dir: str, n: int, seed: int, specs: list[dict], results: list[dict | None], meta: dict) -> dict:
    """DIR/gap_bench.json (draw, summary, cases; "partial": true when some cases never returned),
    gap_bench.md, the plots and report.html — each written whole (atomic)."""
    from .gapplots import confusion_table, overall_table, per_type_table, write_report

    done = [r for r in results if r is not None]
    summary = gapstats.summarise_random(done)
    doc = {"random": {"n": n, "seed": seed, "cases": specs}, "partial": len(done) < n, **meta,
           "summary": summary, "cases": done}
    atomic_write_json(os.path.join(out_dir, "gap_bench.json"), doc)
    md = ("# gap-bench (random)\n\n" + (f"**partial: {len(done)} of {n} cases**\n\n" if doc["partial"] else "")
          + overall_table(summary) + "\n\n" + per_type_table(summary) + "\n\nConfusion (counts):\n\n"
          + confusion_table(summary["confusion"]) + "\n\n" + gapbench.table(done)
          + "\n\n```json\n" + json.dumps(summary, indent=1) + "\n```\n")
    atomic_write_text(os.path.join(out_dir, "gap_bench.md"), md)
    write_report(out_dir, doc)
    return doc


def random_bench(out_dir: str, n: int, seed: int, jobs: int = 1, scale: float = 1.0,
                 cluster: str | None = None, resume: bool = False) -> dict:
    """Draw N cases from SEED, run them (joblib with `jobs`, or the Dask `cluster`), write the results;
    with `resume`, the cases DIR already finished for this draw are kept, not run again."""
    from ciml_learning.learning.cluster import PartialResults, run_all

    done = finished_cases(out_dir, n, seed) if resume else {}
    os.makedirs(out_dir, exist_ok=True)
    specs = draw(n, seed)
    atomic_write_json(os.path.join(out_dir, "draws.json"), {"n": n, "seed": seed, "cases": specs})
    jobs_list = [(i, spec, os.path.abspath(out_dir), scale) for i, spec in enumerate(specs, start=1)
                 if i not in done]
    t0 = time.time()
    meta = {"scale": scale, "engine": cluster or f"joblib:{jobs}", "resumed_cases": len(done)}

    def merged(new: list) -> list:
        by_case = {**done, **{job[0]: r for job, r in zip(jobs_list, new)}}
        return [by_case.get(i) for i in range(1, n + 1)]

    try:
        results = run_all(random_case, jobs_list, jobs, cluster, module="ciml_sim.gaprandom") if jobs_list else []
    except PartialResults as err:
        write(out_dir, n, seed, specs, merged(err.results), {**meta, "wall_s": round(time.time() - t0, 1)})
        raise
    return write(out_dir, n, seed, specs, merged(results), {**meta, "wall_s": round(time.time() - t0, 1)})


def command(args) -> int:
    """`ciml gap-bench`: the suite (gapbench.gap_bench_command), or with --random N --seed S the random
    bench (`--out DIR [--jobs J | --cluster ADDRESS] [--scale S]`)."""
    from ciml_learning.cli.args import cap_jobs
    from ciml_learning.core.errors import CimlError
    from ciml_learning.core.fileio import check_out_dir
    from ciml_learning.learning.cluster import LOCAL_PREFIX

    from .gapplots import overall_table, per_type_table

    if args.resume and args.random is None:
        raise CimlError("--resume goes on with a --random bench; the suite's cases are few (run them again)")
    if args.random is None:
        return gapbench.gap_bench_command(args)
    check_out_dir(args.out, gapbench.is_gap_bench_dir, "gap-bench output")
    if args.cases:
        raise CimlError("--cases selects suite cases; with --random the draw is the bench (drop --cases)")
    cluster = args.cluster
    if cluster and cluster.startswith(LOCAL_PREFIX):  # a LocalCluster's processes share this machine's cores
        cluster = f"{LOCAL_PREFIX}{cap_jobs(int(cluster[len(LOCAL_PREFIX):]), '--cluster local:N')}"
    doc = random_bench(args.out, args.random, args.seed, cap_jobs(args.jobs), args.scale, cluster, args.resume)
    print(gapbench.table(doc["cases"]))
    print(overall_table(doc["summary"]))
    print(per_type_table(doc["summary"]))
    print(f"gap-bench: {args.random} random cases (seed {args.seed}) in {doc['wall_s']} s; results in "
          f"{os.path.join(args.out, 'gap_bench.json')}, report.html")
    return 0
