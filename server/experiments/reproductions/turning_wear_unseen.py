"""Wear on tools never seen (issue 35): the nested evaluation's rows and checks for
``cutwatch reproduce turning-wear``.

Per signal set and outer protocol (leave one tool out; leave k = 2, 3, 4 tools out, 5
splits each), under the protocol's current revision (4: revision 3's 36 configurations
per set, the prior wear rate's rule - the median at the same conditions or a Taylor-type
law in the cutting speed - chosen in each fold on the training tools' rates): the
hybrid's MAE (median and range over the splits) beside each baseline's, the ratios to
the baselines per split, coverage and width of the CV+ intervals, the selection's
optimism; on leave-one-tool-out also MAE at the measured VB points, per cutting-
condition group, the tools entered part-way, the remaining life at half-life (and taken
apart) and the configurations the folds chose. The condition groups come from the data
(median spindle speed and feed per tool,
:func:`server.pipeline.wear_nested.condition_groups`). Checks (the issue's targets) on
leave-one-tool-out pooled over the nine tools, for the feed force and the drive signals.
``quick``: the feed force, two tools left out one at a time, the protocol's first
candidate list without boosting (30 configurations); its checks are computed the same
way and not expected to hold.
"""

from __future__ import annotations

from typing import Any

from server.experiments.reproduction import Check, Row

#: the signal sets the targets are checked on (the feed force, the drive signals)
CHECKED = ("F_f", "TV2.Z", "CV3.Z", "drives")
QUICK_SETS = ("F_f",)
QUICK_TOOLS = (7, 16)
TARGET_RATIO = 0.75
TARGET_COVERAGE = 0.90
TARGET_TOOL_COVERAGE = 0.75
TARGET_TOOLS = 0.75
TARGET_WIDTH = 6.0
TARGET_LIFE = 0.25


def _rng(d: dict[str, float]) -> str:
    return f"{d['median']:.3g} ({d['min']:.3g}-{d['max']:.3g})"


def protocol_rows(s: str, p: str, v: dict[str, Any]) -> list[Row]:
    """The distribution over the splits of one protocol."""
    n = v["splits"]
    pre = f"unseen.{s}.{p}"
    cond = (
        f"{n} splits, median (range) over them; linear {_rng(v['mae_linear'])}, "
        f"gbr5 {_rng(v['mae_gbr5'])}, gbr_same {_rng(v['mae_gbr_same'])}, "
        f"prior {_rng(v['mae_prior'])}; ours {_rng(v['mae'])}"
    )
    rows = [
        Row(f"{pre}.mae", v["mae"]["median"], v["mae_linear"]["median"], "um", cond),
        Row(
            f"{pre}.mae_knots",
            v["mae_knots"]["median"],
            v["mae_knots_linear"]["median"],
            "um",
            f"at the measured VB points; paper = linear; ours {_rng(v['mae_knots'])}",
        ),
    ]
    for b, target in (("linear", TARGET_RATIO), ("gbr5", 1.0), ("gbr_same", 1.0), ("prior", 1.0)):
        rows.append(
            Row(
                f"{pre}.ratio_{b}",
                v[f"ratio_{b}"]["median"],
                target,
                "",
                f"MAE / {b}'s per split, range {v[f'ratio_{b}']['min']:.2f}-"
                f"{v[f'ratio_{b}']['max']:.2f}; paper = target",
            )
        )
    rows += [
        Row(
            f"{pre}.coverage",
            v["coverage"]["median"],
            TARGET_COVERAGE,
            "",
            f"CV+ 95 % over tools, range {v['coverage']['min']:.2f}-{v['coverage']['max']:.2f}",
        ),
        Row(f"{pre}.width", v["width"]["median"], None, "um", f"median width {_rng(v['width'])}"),
        Row(
            f"{pre}.tools_beat_linear",
            v["tools_beat_linear"],
            TARGET_TOOLS,
            "",
            "fraction of test tools (over all splits) where ours < linear",
        ),
        Row(
            f"{pre}.tools_cov75",
            v["tools_cov75"],
            TARGET_TOOLS,
            "",
            "fraction of test tools with coverage >= 0.75",
        ),
        Row(
            f"{pre}.optimism",
            v["optimism"]["median"],
            0.0,
            "um",
            f"outer - inner score of the chosen configuration per split, range "
            f"{v['optimism']['min']:.1f}-{v['optimism']['max']:.1f}; inner "
            f"{_rng(v['inner_score'])}, outer {_rng(v['outer_score'])}; "
            f"{_rng(v['inner_close'])} of {v['n_configs']} configurations within one "
            "paired S.E. of the best; paper = none",
        ),
    ]
    return rows


def loto_rows(s: str, v: dict[str, Any]) -> list[Row]:
    """Leave-one-tool-out extras: pooled, per tool, groups, entry, life, choices."""
    pre = f"unseen.{s}.loto"
    po = v["pooled"]
    rows = [
        Row(
            f"{pre}.pooled.mae",
            po["mae"],
            po["mae_linear"],
            "um",
            f"all rows of the nine tools; paper = linear; gbr5 {po['mae_gbr5']:.1f}, "
            f"gbr_same {po['mae_gbr_same']:.1f}, prior {po['mae_prior']:.1f}",
        ),
        Row(
            f"{pre}.pooled.mae_knots",
            po["mae_knots"],
            po["mae_knots_linear"],
            "um",
            f"measured VB points only; gbr5 {po['mae_knots_gbr5']:.1f}, "
            f"prior {po['mae_knots_prior']:.1f}",
        ),
        Row(f"{pre}.pooled.coverage", po["coverage"], 0.95, "", "paper = nominal"),
        Row(f"{pre}.pooled.width_over_mae", po["width"] / po["mae"], TARGET_WIDTH, "", ""),
    ]
    for t in v["per_tool"]:
        rows.append(
            Row(
                f"{pre}.tool.{t['tool']}.mae",
                t["mae"],
                t["mae_linear"],
                "um",
                f"paper = linear; gbr5 {t['mae_gbr5']:.1f}, prior {t['mae_prior']:.1f}; "
                f"coverage {t['coverage']:.2f}, width {t['width']:.0f} um",
            )
        )
    for g, gv in v.get("groups", {}).items():
        who = ", ".join(str(t) for t in gv["tools"])
        rows.append(
            Row(
                f"{pre}.group.{g}.mae",
                gv["mae"],
                gv["mae_linear"],
                "um",
                f"tools {who} (spindle speed and feed {g}, CNC units, grouped from the "
                f"data), mean of per-tool MAE; paper = linear; gbr5 {gv['mae_gbr5']:.1f}, "
                f"prior {gv['mae_prior']:.1f}",
            )
        )
    rows += [
        Row(
            f"{pre}.entry.record",
            v["entry_record"],
            None,
            "um",
            "tools entered a third into their life with their record (VB at entry)",
        ),
        Row(
            f"{pre}.entry.no_record",
            v["entry_no_record"],
            None,
            "um",
            "the same with no record: starts from a fresh tool's prior",
        ),
        Row(
            f"{pre}.life_error",
            v["life_error"],
            TARGET_LIFE,
            "",
            f"median |pred - true end| / remaining life at half-life, {v['life_tools']} "
            "tools (300 um, 150 um if never 300); paper = target",
        ),
    ]
    lp = v.get("life_parts", {})
    if lp:
        rows.append(
            Row(
                f"{pre}.life_parts",
                lp["est/est"],
                lp["true/true"],
                "",
                "median life error at half-life: level/rate from the estimate (ours), "
                "paper = the measured VB and its mean rate; true level + our rate "
                f"{lp['true/est']:.2f}, our level + true mean rate {lp['est/true']:.2f}, "
                f"true level + prior rate {lp['true/prior']:.2f}; median level error "
                f"{lp['level_err']:.1f} um",
            )
        )
    for i, (c, n) in enumerate(v["chosen"].items()):
        rows.append(Row(f"{pre}.chosen.{i}", n, None, "folds", c))
    if "rate_laws" in v:
        rows.append(rate_law_row(pre, v))
    return rows


def rate_law_row(pre: str, v: dict[str, Any]) -> Row:
    """The prior rate's rule as it ran: revision 5's law per segment (b from its grid,
    how often the fallback b = 0), else revision 4's choice between the median and the
    Taylor-type law (how often the latter was chosen, its slope clipped)."""
    laws = v["rate_laws"]
    bs = [b for b in v["rate_b"] if b == b]
    b_range = f"{min(bs):.2f}-{max(bs):.2f}" if bs else "none"
    if "segment" in laws:
        n = laws["segment"]
        text = (
            f"folds under the law per segment (revision 5) of {v['splits']}: {laws}; its "
            f"exponent b {b_range} (the grid's values), the fallback b = 0 (too few knot "
            f"intervals for the fit) in {v.get('rate_b_fallback', 0)} folds"
        )
    else:
        n = laws.get("taylor", 0)
        text = (
            f"folds whose training tools chose the Taylor-type prior rate (revision 4) "
            f"of {v['splits']}: {laws}; its exponent b {b_range}, the training tools' "
            f"slope outside the physical range [0.67, 5] (clipped) in "
            f"{v['rate_b_out_of_range']} folds"
        )
    return Row(f"{pre}.rate_law", n, None, "folds", text)


def checks(s: str, v: dict[str, Any]) -> list[Check]:
    """The issue's targets on leave-one-tool-out, pooled over the tools."""
    po = v["pooled"]
    pre = f"unseen.{s}"
    gb = min(po["mae_gbr5"], po["mae_gbr_same"])
    return [
        Check(
            f"{pre}.mae_vs_linear",
            po["mae"] / po["mae_linear"] <= TARGET_RATIO,
            po["mae"] / po["mae_linear"],
            TARGET_RATIO,
        ),
        Check(f"{pre}.mae_vs_gbr", po["mae"] / gb <= 1.0, po["mae"] / gb, 1.0),
        Check(
            f"{pre}.mae_vs_prior",
            po["mae"] / po["mae_prior"] <= 1.0,
            po["mae"] / po["mae_prior"],
            1.0,
        ),
        Check(
            f"{pre}.tools_beat_linear",
            v["tools_beat_linear"] >= TARGET_TOOLS,
            v["tools_beat_linear"],
            TARGET_TOOLS,
        ),
        Check(
            f"{pre}.coverage", po["coverage"] >= TARGET_COVERAGE, po["coverage"], TARGET_COVERAGE
        ),
        Check(
            f"{pre}.tools_cov75",
            v["tools_cov75"] >= TARGET_TOOL_COVERAGE,
            v["tools_cov75"],
            TARGET_TOOL_COVERAGE,
        ),
        Check(
            f"{pre}.width_over_mae",
            po["width"] / po["mae"] <= TARGET_WIDTH,
            po["width"] / po["mae"],
            TARGET_WIDTH,
        ),
        Check(f"{pre}.life_at_half", v["life_error"] <= TARGET_LIFE, v["life_error"], TARGET_LIFE),
    ]


def section(path: Any, quick: bool, bar: Any) -> tuple[list[Row], list[Check]]:
    """Run the nested evaluation and turn it into rows and checks."""
    from estimators.wear.hybrid import RATE_LAWS, candidates
    from server.pipeline.wear_nested import (
        SETS,
        condition_groups,
        evaluate,
        load,
        outer_splits,
        summarise,
    )

    sets = QUICK_SETS if quick else tuple(SETS)
    table = load(path, sets)
    groups = condition_groups(table)
    splits = [("loto", (t,)) for t in QUICK_TOOLS] if quick else outer_splits(table.tools)
    res = evaluate(
        table,
        sets,
        splits,
        configs=[c for c in candidates(revision=1) if c.map != "gbr"] if quick else None,
        progress=bar.update,
        rate_laws=RATE_LAWS,
    )
    rows: list[Row] = []
    chk: list[Check] = []
    for s in sets:
        summ = summarise(res[s], groups)
        for p, v in summ.items():
            rows += protocol_rows(s, p, v)
            if p == "loto":
                rows += loto_rows(s, v)
                if s in CHECKED:
                    chk += checks(s, v)
    return rows, chk


def total(quick: bool, n_tools: int) -> int:
    """Progress-bar steps (one per outer split and set)."""
    from server.pipeline.wear_nested import K_OUT, SETS, SPLITS_PER_K

    if quick:
        return len(QUICK_SETS) * len(QUICK_TOOLS)
    return len(SETS) * (n_tools + len(K_OUT) * SPLITS_PER_K)
