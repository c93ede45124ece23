"""The experiment report: the paper's colouring, a report over real runs, seed and noise aggregation, bad input."""

from __future__ import annotations

import json
import math
import re
import shutil
import statistics
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from liquidgs.commands.train import main as train_main
from liquidgs.data import generate_synthetic
from liquidgs.errors import LiquidGSError
from liquidgs.experiments import Experiment, RunEntry, expand, spec_from_dict, write_manifest
from liquidgs.experiments.report import write_report
from liquidgs.experiments.report.aggregate import DatasetScores
from liquidgs.experiments.report.collect import Method
from liquidgs.experiments.report.figures import PANEL, crop_window
from liquidgs.experiments.report.references import MEAN, paper_targets
from liquidgs.experiments.report.tables import METRICS, Cell, Row, Table, to_latex
from liquidgs.experiments.report.write import portable_paths, score_table
from liquidgs.experiments.runner import train_command
from liquidgs.fields.config import PAPER_LAMBDA
from liquidgs.train.config import preset_config, save_yaml
from shared_data import PAPER_DIR, require_shared, use_optional_lpips
from tiny_runs import tiny_overrides

PAPER = PAPER_DIR / "000_90a69819efc025de.txt"
TARGETS = PAPER_DIR / "targets.json"
RANK_BY_NAME = {"best": 0, "second": 1, "third": 2}
RANK_BY_COLOUR = {"red!60": 0, "orange!57": 1, "yellow!55": 2}


# ------------------------------------------------------------------ parsing coloured LaTeX tables
def parse_cell(text: str) -> tuple[int | None, float]:
    """A cell as (rank or None, value), from the paper's \\best{..} macros or our \\cellcolor{..}."""
    text = text.strip()
    if m := re.fullmatch(r"\\(best|second|third)\{(.*)\}", text):
        return RANK_BY_NAME[m[1]], float(m[2])
    if m := re.fullmatch(r"\\cellcolor\{([^}]*)\}(.*)", text):
        return RANK_BY_COLOUR[m[1]], float(m[2].split("$")[0])
    if text == "-":  # a cell a row has no number for
        return None, math.nan
    return None, float(text.split("$")[0])


def parse_blocks(tex: str) -> list[tuple[list[str], list[tuple[str, list[tuple[int | None, float]]]]]]:
    """Each block of a tabular: its group titles and its rows (label, cells)."""
    blocks = []
    for line in tex.splitlines():
        line = line.strip()
        if "\\multicolumn" in line:
            blocks.append((re.findall(r"\\multicolumn\{\d+\}\{[^}]*\}\{([^}]*)\}", line), []))
        elif blocks and "&" in line and line.endswith("\\\\") and not line.startswith(("Method", "$\\lambda$")):
            label, *cells = line[:-2].split("&")
            blocks[-1][1].append((label.strip(), [parse_cell(c) for c in cells]))
    return blocks


def scene_key(title: str) -> str:
    return re.sub(r"[^a-z]", "", title.lower())


def colouring(tex: str, methods: dict[str, dict[str, list[float]]]) -> dict[tuple[str, str, str], int]:
    """(method, scene, metric) -> rank for every coloured cell; rows are identified by their numbers."""
    out = {}
    for titles, rows in parse_blocks(tex):
        scenes = [scene_key(t) for t in titles]
        for _, cells in rows:
            values = {s: [v for _, v in cells[3 * i : 3 * i + 3]] for i, s in enumerate(scenes)}
            [method] = [name for name, per in methods.items() if all(per[s] == values[s] for s in scenes)]
            for i, scene in enumerate(scenes):
                for j, metric in enumerate(("psnr", "ssim", "lpips")):
                    rank = cells[3 * i + j][0]
                    if rank is not None:
                        out[(method, scene, metric)] = rank
    return out


def paper_table(label: str) -> str:
    source = require_shared(PAPER).read_text()
    start = source.index(f"\\label{{{label}}}")
    return source[start : source.index("\\end{tabular}", start)]


@pytest.mark.parametrize(("label", "key"), [("tab:dnerf", "dnerf_table"), ("tab:nerfds", "nerfds_table")])
def test_colouring_matches_the_papers_tables(label, key):
    table = json.loads(require_shared(TARGETS).read_text())[key]
    methods = table["methods"]
    expected = colouring(paper_table(label), methods)
    rows = [Row(name, name, {(s, m.key): Cell(v[i]) for s, v in per.items() for i, m in enumerate(METRICS)})
            for name, per in methods.items()]  # fmt: skip
    ours = to_latex(Table(list(table["scenes"]), METRICS, rows, "", "", label))
    assert len(expected) >= 3 * len(table["scenes"]) * 3 - 5  # the parse found the coloured cells
    assert colouring(ours, methods) == expected


def report_colouring(tex: str, names: dict[str, str], scenes: list[str]) -> dict[tuple[str, str, str], int]:
    """(method, scene, metric) -> rank for the coloured cells of the rows `names` maps (LaTeX label -> method)."""
    out = {}
    for titles, rows in parse_blocks(tex):
        for label, cells in rows:
            for i, scene in enumerate(scene_key(t) for t in titles):
                for j, metric in enumerate(("psnr", "ssim", "lpips")):
                    rank = cells[3 * i + j][0]
                    if rank is not None:
                        assert label in names, f"an unranked row is coloured: {label}"
                        if scene in scenes:
                            out[(names[label], scene, metric)] = rank
    return out


@pytest.mark.parametrize(("label", "key", "dataset"), [("tab:dnerf", "dnerf_table", "dnerf"),
                                                       ("tab:nerfds", "nerfds_table", "nerfds")])  # fmt: skip
def test_with_references_our_rows_are_coloured_as_the_paper_colours_them(label, key, dataset):
    """The paper's own MLP and SDE-LNN numbers fed to the report as our runs: with --references it ranks
    them with the baselines the paper quotes (D-NeRF, TiNeuVox, NeRF-DS) and colours exactly the cells
    the paper's LaTeX colours, its quoted rows included."""
    table = json.loads(require_shared(TARGETS).read_text())[key]
    methods, scenes = table["methods"], [s for s in table["scenes"] if s != MEAN]
    ours = {Method.of("mlp", 0.0): "D-3DGS (MLP)", Method.of("sde", PAPER_LAMBDA): "SDE-LNN"}
    values = {(method, scene, metric.key): {0: methods[name][scene][i]}
              for method, name in ours.items() for scene in scenes for i, metric in enumerate(METRICS)}  # fmt: skip
    scores = DatasetScores(dataset, scenes, sorted(ours), values, [])
    names = {method.latex_label: name for method, name in ours.items()}
    names |= {name: name for name in methods if name not in ours.values()}  # the quoted baselines
    expected = colouring(paper_table(label), methods)
    printed_scenes = {scene for _, scene, _ in expected}
    assert len(expected) >= 3 * len(printed_scenes) * 3 - 5  # the parse found the coloured cells

    with_references, _ = score_table(scores, "final", references=True)
    tex = to_latex(with_references)
    assert report_colouring(tex, names, sorted(printed_scenes)) == expected
    assert "Paper: D-3DGS (MLP)" in tex and "D-3DGS published" in tex  # shown, not ranked (checked above)
    if dataset == "dnerf":
        # Ranked among our two rows only, lego's PSNR would be SDE-LNN best; the paper has it third.
        assert expected[("SDE-LNN", "lego", "psnr")] == 2
        alone, _ = score_table(scores, "final", references=False)
        assert report_colouring(to_latex(alone), names, ["lego"])[("SDE-LNN", "lego", "psnr")] == 0


def test_noise_study_colouring_matches_the_papers_table_iv():
    study = json.loads(require_shared(TARGETS).read_text())["noise_study_means"]
    lambdas = [k for k in study if k != "columns"]
    rows = [Row(lam, lam, {(d, m.key): Cell(study[lam][3 * g + i]) for g, d in enumerate(("dnerf", "nerfds"))
                           for i, m in enumerate(METRICS)}) for lam in lambdas]  # fmt: skip
    ours = to_latex(Table(["dnerf", "nerfds"], METRICS, rows, "", "", "tab:abl", colours=1, row_header="$\\lambda$"))

    def best_cells(tex: str) -> set[tuple[str, int]]:
        [(_, parsed)] = parse_blocks(tex)
        return {(label, i) for label, cells in parsed for i, (rank, _) in enumerate(cells) if rank == 0}

    expected = best_cells(paper_table("tab:abl"))
    assert len(expected) == 8  # the two tied 38.28s and 0.9856s both best, as printed
    assert best_cells(ours) == expected


def test_shipped_targets_are_the_shared_numbers():
    shipped = {k: v for k, v in paper_targets().items() if k != "_source"}
    assert shipped == json.loads(require_shared(TARGETS).read_text())
    assert "targets.json" in paper_targets()["_source"]


# ------------------------------------------------------------------ a small real experiment
# Three evaluations per run (8, 16, 24), for the report's final / best-of numbers.
FAST = tiny_overrides({
    "iterations": 24, "warmup": 6, "init_points": 400, "densify.start": 6, "densify.interval": 6,
    "eval.start": 8, "eval.every": 8, "eval.fps_frames": 2, "checkpoint_every": 12,
})  # fmt: skip


@pytest.fixture(scope="module")
def experiment(tmp_path_factory) -> Path:
    """2 scenes (named like D-NeRF scenes, so references apply) x mlp / sde, tiny preset, 24 iterations."""
    root = tmp_path_factory.mktemp("report")
    for scene, synthetic in (("hook", "puppet"), ("lego", "spinner")):
        generated = generate_synthetic(synthetic, root / "gen" / scene, size=32, frames=20, seed=3)
        shutil.copytree(Path(generated) / "dnerf", root / "data" / "dnerf" / scene)
    spec = spec_from_dict({"name": "small", "dataset": "dnerf", "preset": "tiny", "scenes": ["hook", "lego"],
                           "fields": ["mlp", "sde"], "overrides": FAST}, "test")  # fmt: skip
    directory = root / "exp"
    plan = expand(spec, root / "data", directory)
    write_manifest(plan)
    with pytest.MonkeyPatch.context() as mp:
        use_optional_lpips(mp)
        for run in plan.runs:
            assert train_main(train_command(run, directory)[4:]) == 0
    return directory


def results_of(directory: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted(directory.rglob("results.json"))]


def test_report_holds_every_runs_final_numbers_and_the_figure(experiment, tmp_path):
    report = write_report(experiment, tmp_path / "final")
    text, tex = report.read_text(), (tmp_path / "final" / "tables.tex").read_text()
    runs = results_of(experiment)
    assert len(runs) == 4
    for res in runs:
        for key, digits in (("psnr", 2), ("ssim", 4)):
            assert f"{res['final'][key]:.{digits}f}" in text
            assert f"{res['final'][key]:.{digits}f}" in tex
        assert f"{res['field_parameters']:,}" in text
    assert "final evaluation" in text and "best-of" not in text.split("## Per-scene")[1].split("##")[0]
    lpips = runs[0]["final"]
    assert (f"LPIPS-{lpips['lpips_backbone']}" if lpips["lpips"] is not None else "LPIPS: unavailable") in text
    assert "\\cellcolor{red!60}" in tex and "\\toprule" in tex and "\\multicolumn{3}{c|}{Hook}" in tex
    # one seed: no measured spread, the paper's sigma instead, said so
    assert "no spread can be measured" in text and "0.05 dB" in text
    # 2 scenes x 1 seed: 2 paired runs, under the 6 a lead or a tie needs
    assert re.search(r"Dataset mean: .* leads with .*; 2 paired scene-seed runs, fewer than the 6 a call needs: "
                     r"too few runs to call\.", text)  # fmt: skip
    assert "None: every planned run finished." in text
    assert "## Noise study" not in text  # one lambda
    figure = tmp_path / "final" / "qualitative_dnerf.png"
    width, height = Image.open(figure).size
    assert (width, height) == (3 * PANEL, 2 * PANEL)  # both scenes have an MLP / SDE-LNN pair
    assert "![ground truth | MLP | SDE-LNN](qualitative_dnerf.png)" in text
    assert len(re.findall(r"^- \([ab]\) (hook|lego): [+-]\d+\.\d\d dB on the scene", text, re.M)) == 2


def test_best_of_report_uses_the_best_of_numbers(experiment, tmp_path):
    text = write_report(experiment, tmp_path, evaluation="best_of").read_text()
    for res in results_of(experiment):
        assert f"{res['best_of']['psnr']:.2f}" in text
    assert "best-of evaluation" in text


def test_reference_rows_and_differences(experiment, tmp_path):
    text = write_report(experiment, tmp_path, references=True).read_text()
    tex = (tmp_path / "tables.tex").read_text()
    hook_mlp = paper_targets()["dnerf_table"]["methods"]["D-3DGS (MLP)"]["hook"][0]
    assert f"| Paper: D-3DGS (MLP) | {hook_mlp:.2f} |" in text and "Paper: SDE-LNN" in tex
    ours = next(r for r in results_of(experiment) if r["field"] == "mlp" and "hook" in r["data"])
    assert f"| D-3DGS (MLP) − Paper: D-3DGS (MLP) | {ours['final']['psnr'] - hook_mlp:+.2f} |" in text
    published = paper_targets()["d3dgs_published"]["dnerf"]["hook"][0]
    assert f"{ours['final']['psnr'] - published:+.2f}" in text
    assert "printed reference means cover other scenes" in text  # 2 of 8 scenes: no mean compared


def test_missing_runs_are_listed_and_each_run_counted_once(experiment, tmp_path):
    copy = tmp_path / "exp"
    shutil.copytree(experiment, copy, ignore=shutil.ignore_patterns("report", "tensorboard"))
    manifest = json.loads((copy / "experiment.json").read_text())
    manifest["runs"].append(manifest["runs"][0])  # listed twice
    (copy / "experiment.json").write_text(json.dumps(manifest))
    gone = manifest["runs"][3]
    (copy / gone["run_dir"] / "results.json").unlink()
    text = write_report(copy).read_text()
    assert "3 of 4 planned runs finished; 1 missing" in text
    assert f"`{gone['run_dir']}`" in text.split("## Missing runs")[1]


def test_crop_window_finds_the_region_where_errors_differ():
    improvement = np.zeros((32, 32))
    improvement[20:28, 4:12] = -1.0  # SDE-LNN better there
    assert crop_window(improvement, 8) == (4, 20)


# ------------------------------------------------------------------ hand-built results: seeds and noise study
def fake_results(psnr: float, ssim: float, lpips: float) -> dict:
    scores = {"psnr": psnr, "ssim": ssim, "lpips": lpips, "lpips_backbone": "vgg", "lpips_version": "0.1",
              "lpips_normalize": False}  # fmt: skip
    return {"final": scores, "best_of": {**scores, "psnr": psnr + 0.5}, "fps": 100.0, "num_gaussians": 1000,
            "field_parameters": 5000, "field_flops_per_gaussian": 9000, "train_seconds": 10.0,
            "peak_memory_mb": 300.0, "peak_memory_kind": "process_peak_rss", "device": "cpu",
            "resolution": [32, 32]}  # fmt: skip


def fake_psnr(scene: str, field: str, lam: float, seed: int) -> float:
    return 30.0 + (scene == "lego") * 2 + (field == "sde") * (1.0 - 8 * lam) + 0.1 * seed


@pytest.fixture
def hand_built(tmp_path) -> Path:
    """dnerf: hook, lego x (mlp, sde at lambda 0 / 0.05 / 0.1) x seeds 0-2, results written by hand."""
    directory, data = tmp_path / "exp", tmp_path / "data"
    data.mkdir()
    runs = []
    for scene in ("hook", "lego"):
        for field, lam in (("mlp", 0.0), ("sde", 0.0), ("sde", 0.05), ("sde", 0.1)):
            for seed in (0, 1, 2):
                run_dir = f"dnerf/{scene}/{field}/l{lam}-s{seed}"
                runs.append(RunEntry("dnerf", scene, field, lam, seed, "tiny", str(data), run_dir, None))
                cfg = preset_config("tiny", data)
                cfg.field, cfg.seed, cfg.lambda_ = field, seed, lam
                save_yaml(cfg, directory / run_dir / "config.yml")
                psnr = fake_psnr(scene, field, lam, seed)
                (directory / run_dir / "results.json").write_text(json.dumps(fake_results(psnr, 0.9, 0.1)))
    write_manifest(Experiment({"name": "hand"}, str(data), directory, tuple(runs)))
    return directory


def test_seeds_are_aggregated_as_mean_and_std_and_the_noise_study_is_built(hand_built):
    text = write_report(hand_built).read_text()
    hook_mlp = [fake_psnr("hook", "mlp", 0.0, s) for s in (0, 1, 2)]
    assert f"{statistics.mean(hook_mlp):.2f} ± {statistics.stdev(hook_mlp):.2f}" in text
    assert "| hook | D-3DGS (MLP) | 3 | 30.00-30.20 | 0.100 |" in text
    assert "measured here" in text and "no spread can be measured" not in text
    # the dataset mean's spread is over the per-seed dataset means
    mean_sde0 = [statistics.mean(fake_psnr(s, "sde", 0.0, seed) for s in ("hook", "lego")) for seed in (0, 1, 2)]
    assert f"**{statistics.mean(mean_sde0):.2f} ± {statistics.stdev(mean_sde0):.2f}**" in text.split("## Noise")[1]
    noise = text.split("## Noise study")[1].split("##")[0]
    assert noise.index("SDE-LNN (lambda 0)") < noise.index("SDE-LNN (lambda 0.1)")
    assert "| lambda | dnerf (2 scenes) PSNR |" in noise
    assert "\\multicolumn{3}{c}{dnerf (2 scenes)}" in (hand_built / "report" / "tables.tex").read_text()
    assert (hand_built / "report" / "noise_study.png").stat().st_size > 1000
    assert "error bars: std over seeds" in text
    assert "LPIPS-vgg v0.1, [0,1] inputs fed as [-1,1]" in text
    # sde at lambda 0 leads its runner-up (lambda 0.05) by 0.4 dB on all 6 scene-seed pairs: the interval
    # [0.4, 0.4] lies above 2 sigma (0.2 dB), a lead; per scene, 3 paired runs are too few to call
    assert re.search(r"Dataset mean: SDE-LNN \(lambda 0\) leads with \S+ dB, 0\.40 dB ahead of SDE-LNN \(lambda "
                     r"0\.05\) \(\S+ dB\); over 6 paired scene-seed runs, 95% t-interval \[\+0\.40, \+0\.40\] dB; .* "
                     r"this is a lead\.", text)  # fmt: skip
    assert "- hook: SDE-LNN (lambda 0) leads" in text
    assert "; 3 paired scene-seed runs, fewer than the 6 a call needs: too few runs to call." in text
    assert "Figure skipped: " in text or "skipped: " in text  # no per_view.json in the hand-built runs
    best_of = write_report(hand_built, evaluation="best_of").read_text()
    assert f"{statistics.mean(hook_mlp) + 0.5:.2f} ± {statistics.stdev(hook_mlp):.2f}" in best_of


def test_the_noise_studys_lambda_0_row_is_read_from_the_cfc_runs(tmp_path):
    """An SDE row at lambda 0 planned as the CfC's run (plan.cfc_twin): one folder, two rows, and the
    noise study's lambda 0 row labelled as the CfC's."""
    directory, data = tmp_path / "exp", tmp_path / "data"
    data.mkdir()
    runs = []
    for scene in ("hook", "lego"):
        for field, lam in (("cfc", 0.0), ("sde", 0.0), ("sde", 0.05), ("sde", 0.1)):
            trained = "cfc" if lam == 0 else field
            run_dir = f"dnerf/{scene}/{trained}/l{lam}"
            runs.append(RunEntry("dnerf", scene, field, lam, 0, "tiny", str(data), run_dir, {"field": trained}))
            if field == "sde" and lam == 0:
                continue  # the CfC's folder, written for its row
            cfg = preset_config("tiny", data)
            cfg.field, cfg.lambda_ = trained, (lam if trained == "sde" else None)
            save_yaml(cfg, directory / run_dir / "config.yml")
            psnr = fake_psnr(scene, "sde", lam, 0)
            (directory / run_dir / "results.json").write_text(json.dumps(fake_results(psnr, 0.9, 0.1)))
    write_manifest(Experiment({"name": "shared"}, str(data), directory, tuple(runs)))
    text = write_report(directory).read_text()
    assert "8 of 8 planned runs finished" in text
    noise = text.split("## Noise study")[1].split("##")[0]
    mean_0 = statistics.mean(fake_psnr(s, "sde", 0.0, 0) for s in ("hook", "lego"))
    assert f"| SDE-LNN (lambda 0) = Liquid CfC | **{mean_0:.2f}** |" in noise
    assert "the CfC's runs. At lambda 0 the SDE field is the CfC bit for bit" in noise
    assert "0.00 (CfC) & " in (directory / "report" / "tables.tex").read_text()


def test_a_tie_is_called_a_tie(hand_built):
    """SDE-LNN at lambda 0 ahead of the MLP by 0.05 dB, under 2 sigma (0.2 dB): a tie."""
    for path in hand_built.rglob("results.json"):
        raw = json.loads(path.read_text())
        lam, seed = (float(v) for v in path.parent.name[1:].split("-s"))
        if "/sde/" in path.as_posix():
            mlp = fake_psnr(path.parts[-4], "mlp", 0.0, int(seed))
            raw["final"]["psnr"] = mlp + 0.05 - 10 * lam
        path.write_text(json.dumps(raw))
    text = write_report(hand_built).read_text()
    assert re.search(r"Dataset mean: SDE-LNN \(lambda 0\) leads with \S+ dB, 0\.05 dB ahead of D-3DGS \(MLP\)"
                     r".* this is a tie\.", text)  # fmt: skip


def test_the_report_names_no_absolute_path_of_the_machine_that_wrote_it(hand_built, tmp_path):
    """The experiment folder by its name, the data root by its folder name, a missing run relative to the
    experiment folder, the torch cache an LPIPS reason names as ~/.cache/...: a committed report holds
    no path of the machine it was written on."""
    results = sorted(hand_built.rglob("results.json"))
    cache = "/home/someone/.cache/torch/hub/checkpoints/alexnet-owt-7be5be79.pth"
    for path in results[1:]:
        raw = json.loads(path.read_text())
        raw["final"].update(lpips=None, lpips_unavailable=f"LPIPS-Alex unavailable: looked for: {cache} (pass x)")
        path.write_text(json.dumps(raw))
    missing = results[0].parent.relative_to(hand_built).as_posix()
    results[0].unlink()
    text = write_report(hand_built).read_text()
    tex = (hand_built / "report" / "tables.tex").read_text()
    assert "Experiment folder `exp` (run folders below are relative to it), data root `data`." in text
    assert f": `{missing}`" in text.split("## Missing runs")[1]
    assert "looked for: ~/.cache/torch/hub/checkpoints/alexnet-owt-7be5be79.pth (pass x)" in text
    assert r"looked for: \textasciitilde{}/.cache/torch/hub/checkpoints/alexnet-owt-7be5be79.pth" in tex
    for written in (text, tex):
        assert str(tmp_path) not in written and "/home/" not in written, written
    assert "1/8" in portable_paths("at 1/8, see https://example.org/a/b", hand_built, tmp_path / "data")
    assert portable_paths(f"in {tmp_path}/data/dnerf/lego and {hand_built}/dnerf", hand_built,
                          tmp_path / "data") == "in data/dnerf/lego and dnerf"  # fmt: skip


# ------------------------------------------------------------------ bad input
def test_a_folder_without_a_manifest_is_one_line_error(tmp_path):
    with pytest.raises(LiquidGSError, match="experiment.json") as err:
        write_report(tmp_path)
    assert "\n" not in str(err.value)


def test_a_corrupt_results_file_is_one_line_error_naming_it(hand_built):
    path = next(hand_built.rglob("results.json"))
    path.write_text('{"final": {"psnr": 3')
    with pytest.raises(LiquidGSError) as err:
        write_report(hand_built)
    assert str(path) in str(err.value) and "\n" not in str(err.value)
    path.write_text(json.dumps({**fake_results(30, 0.9, 0.1), "final": {"psnr": "high", "ssim": 0.9}}))
    with pytest.raises(LiquidGSError, match=r"field 'final.psnr'"):
        write_report(hand_built)
    path.write_text(json.dumps({**fake_results(30, 0.9, 0.1), "format": "liquidgs-results-9"}))
    with pytest.raises(LiquidGSError, match=r"results format 'liquidgs-results-9' is not one this liquidgs reads"):
        write_report(hand_built)


def test_unknown_evaluation_is_refused(hand_built):
    with pytest.raises(LiquidGSError, match="--eval"):
        write_report(hand_built, evaluation="median")


# ------------------------------------------------------------------ Table III
# Each field's parameter count under the paper presets (build_field(FieldConfig(name, preset))).
FIELD_PARAMETERS = {("dnerf", "mlp"): 522_280, ("nerfds", "mlp"): 506_378,
                    ("dnerf", "cfc"): 1_553_706, ("nerfds", "cfc"): 318_602}  # fmt: skip


def cost_rows(tex: str) -> list[tuple[str, str, str]]:
    """(label, params cell, inference) of the table labelled tab:cost."""
    start = tex.index("\\label{tab:cost}")
    body = tex[start : tex.index("\\end{tabular}", start)]
    lines = [ln.strip() for ln in body.splitlines() if ln.strip().endswith("\\\\")]
    return [tuple(cell.strip() for cell in ln[:-2].split("&")) for ln in lines]


def test_cost_table_is_the_papers_table_iii_in_layout_and_colouring(tmp_path):
    """MLP, CfC and SDE-LNN runs on D-NeRF and NeRF-DS scenes with the presets' real field sizes: one
    coloured table in Table III's layout, the CfC and SDE-LNN sharing a row per dataset, the paper's
    0.32 M and 1.55 M, and the smallest coloured best as the paper colours it."""
    directory, data = tmp_path / "exp", tmp_path / "data"
    data.mkdir()
    runs = []
    for dataset, scene in (("dnerf", "hook"), ("nerfds", "bell")):
        for field, lam in (("mlp", 0.0), ("cfc", 0.0), ("sde", 0.05)):
            run_dir = f"{dataset}/{scene}/{field}"
            runs.append(RunEntry(dataset, scene, field, lam, 0, dataset, str(data), run_dir, {"field": field}))
            cfg = preset_config(dataset, data)
            cfg.field, cfg.lambda_ = field, (lam if field == "sde" else None)
            save_yaml(cfg, directory / run_dir / "config.yml")
            params = FIELD_PARAMETERS[(dataset, "cfc" if field == "sde" else field)]
            results = {**fake_results(30.0, 0.9, 0.1), "field_parameters": params}
            (directory / run_dir / "results.json").write_text(json.dumps(results))
    write_manifest(Experiment({"name": "cost"}, str(data), directory, tuple(runs)))
    write_report(directory, references=True)
    tex = (directory / "report" / "tables.tex").read_text()
    rows = cost_rows(tex)
    assert rows[0] == ("Deformation field", "Params (M)", "Inference")
    assert "\\begin{tabular}{l|c|c}" in tex.split("\\label{tab:cost}")[1].split("\\end{tabular}")[0]
    assert rows[1:5] == [
        ("D-3DGS (MLP) --- NeRF-DS", "0.51", "feed-forward"),
        ("D-3DGS (MLP) --- D-NeRF", "0.52", "feed-forward"),
        ("Liquid CfC / SDE-LNN --- NeRF-DS", "\\cellcolor{red!60}0.32", "feed-forward"),
        ("Liquid CfC / SDE-LNN --- D-NeRF", "1.55", "feed-forward"),
    ]
    # The paper's printed rows follow, not ranked: its 0.32 is not coloured beside ours.
    assert rows[5:] == [("Paper: D-3DGS MLP (D=8, W=256)", "0.52", "feed-forward"),
                        ("Paper: Liquid CfC / SDE-LNN, NeRF-DS preset", "0.32", "feed-forward"),
                        ("Paper: Liquid CfC / SDE-LNN, D-NeRF preset", "1.55", "feed-forward")]  # fmt: skip
    # The paper's own Table III: the same values, and its one coloured cell is the same row's.
    paper = paper_table("tab:cost")
    assert "Deformation field & Params (M) & Inference" in paper and "\\best{0.32}" in paper
    assert {"0.32", "1.55"} <= set(re.findall(r"\d\.\d\d", paper))
    text = (directory / "report" / "report.md").read_text()
    assert "| Liquid CfC / SDE-LNN — NeRF-DS | **0.32** | feed-forward |" in text


def test_cost_table_colours_the_smallest_at_printed_precision_and_ties_share_it():
    from liquidgs.experiments.report.tables import SizeRow, size_table

    sizes = {"a": 0.524, "b": 0.3249, "c": 0.3201}
    rows = [SizeRow(k, k, v, "feed-forward") for k, v in sizes.items()] + [SizeRow("p", "p", 0.1, "ff", ranked=False)]
    markdown, latex = size_table(rows, "cap", "cap", "tab:cost")
    # 0.3249 and 0.3201 both print as 0.32: both best; the unranked 0.10 is not
    assert "| b | **0.32** |" in markdown and "| c | **0.32** |" in markdown and "| p | 0.10 | ff |" in markdown
    assert latex.count("\\cellcolor{red!60}") == 2 and "orange" not in latex


def test_aligned_and_masked_scores_have_their_own_labelled_columns(hand_built):
    """A run that refined its cameras (final_aligned) and one scored with `eval --mask`: their second
    scores appear in their own columns, the per-scene tables keep the given-camera scores only."""
    refined = hand_built / "dnerf/hook/mlp/l0.0-s0"
    results = json.loads((refined / "results.json").read_text())
    results["final_aligned"] = {"psnr": 41.23, "ssim": 0.9876, "cameras": "each test camera aligned (protocol)"}
    (refined / "results.json").write_text(json.dumps(results))
    masked = hand_built / "dnerf/lego/mlp/l0.0-s1"
    (masked / "eval.json").write_text(json.dumps({"masked": {"masks": "m", "cameras": "as given",
                                                             "inside": {"psnr": 17.89, "ssim": 0.5, "share": 0.2},
                                                             "outside": {"psnr": 35.67, "ssim": 0.9, "share": 0.8}},
                                                  "masked_aligned": {"masks": "m", "cameras": "aligned (protocol)",
                                                             "inside": {"psnr": 19.01, "ssim": 0.6, "share": 0.2},
                                                             "outside": {"psnr": 37.02, "ssim": 0.9, "share": 0.8}}}))
    text = write_report(hand_built).read_text()
    main, section = text.split("## Aligned and masked scores")[0], text.split("## Aligned and masked scores")[1]
    assert not any(score in main for score in ("41.23", "17.89", "35.67", "19.01", "37.02"))  # never mixed in
    section = section.split("\n## ")[0]
    assert "PSNR, test cameras as given (final) | PSNR, test cameras aligned (final)" in section
    assert "each test camera aligned (protocol)" in section
    hook = fake_psnr("hook", "mlp", 0.0, 0)
    assert f"| dnerf / hook | D-3DGS (MLP) | 0 | {hook:.2f} | 41.23 | 0.9876 | - | - | - | - |" in section
    lego = fake_psnr("lego", "mlp", 0.0, 1)
    assert f"| dnerf / lego | D-3DGS (MLP) | 1 | {lego:.2f} | - | - | 17.89 | 35.67 | 19.01 | 37.02 |" in section
    assert section.count("| dnerf /") == 2  # runs without second scores get no row
    (masked / "eval.json").write_text(json.dumps({"masked": {"inside": {}}}))
    with pytest.raises(LiquidGSError, match="eval.json: field 'masked' must be an object with inside, outside"):
        write_report(hand_built)
    (masked / "eval.json").write_text(json.dumps({"masked_aligned": {"outside": {}}}))
    with pytest.raises(LiquidGSError, match="eval.json: field 'masked_aligned' must be an object with inside"):
        write_report(hand_built)
