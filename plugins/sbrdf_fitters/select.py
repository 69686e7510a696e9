"""Select: keep, for the whole material, the fitted model with the lowest held-out error.

Which model suits a material is a question the training RMS cannot answer:
the model with more parameters always fits its training samples better.
The Fit node scores every texel at samples it held out (``rms_holdout``); this
node compares those scores between the ParamMaps it is given and passes the
winner on unchanged, with the comparison and the reason in its attributes::

    fit_laf: {kind: Fit, plugin: lm, in: {samples: reflectance}, params: {model: lafortune, model_params: {lobes: 2}}}
    fit_ct:  {kind: Fit, plugin: lm, in: {samples: reflectance}, params: {model: cook-torrance}}
    fit_ward: {kind: Fit, plugin: lm, in: {samples: reflectance}, params: {model: ward}}
    best:    {kind: Select, in: {a: fit_laf, b: fit_ct, c: fit_ward}}
"""

from __future__ import annotations

import logging

from sbrdf_core.artifacts import ParamMaps
from sbrdf_core.errors import SbrdfError
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output, Port
from sbrdf_core.params import Param

log = logging.getLogger("sbrdf.select")

#: Candidate ports: the first two are required, the rest optional.
SLOTS = "abcdefgh"


def score(art, by: str) -> tuple[float | None, str]:
    """The candidate's figure of merit and where it came from (held-out RMS, or training RMS as a fallback)."""
    summary = art.attrs.get("summary", {})
    held = summary.get("rms_holdout_mean")
    if by == "holdout" and held is not None:
        return float(held), "held-out RMS"
    train = summary.get("rms_mean")
    return (None if train is None else float(train)), "training RMS"


class Select(NodeKind):
    name = "Select"
    doc = "Keep the fitted ParamMaps with the lowest mean held-out RMS (model selection for the whole material)."
    inputs = tuple(Port(s, (ParamMaps,), f"candidate fit {s}", optional=i >= 2) for i, s in enumerate(SLOTS))
    output = ParamMaps
    params = (
        Param("by", "str", "holdout", "figure compared: mean held-out RMS (holdout), or mean training RMS (training: "
              "favours the model with more parameters)", choices=("holdout", "training")),
    )

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        by = ctx.params["by"]
        table = {}
        for port, art in ctx.inputs.items():
            value, what = score(art, by)
            summary = art.attrs.get("summary", {})
            table[port] = {"artifact": art.url, "model": art.attrs.get("model"), "model_config": art.attrs.get("model_config"),
                           "score": value, "scored_by": what, "rms_mean": summary.get("rms_mean"),
                           "rms_holdout_mean": summary.get("rms_holdout_mean"), "fit_time_s": summary.get("fit_time_s")}
        ranked = sorted((c for c in table.items() if c[1]["score"] is not None), key=lambda c: c[1]["score"])
        if not ranked:
            raise SbrdfError(f"node {ctx.node!r}: no candidate has an error summary to compare")
        port, best = ranked[0]
        if best["scored_by"] != ("held-out RMS" if by == "holdout" else "training RMS"):
            log.warning("node %r: %s has no held-out error (fitted with holdout: 0); compared by training RMS",
                        ctx.node, best["artifact"])
        runner_up = f"; next {ranked[1][1]['model']} at {ranked[1][1]['score']:.4g}" if len(ranked) > 1 else ""
        why = (f"{best['model']} ({port}) has the lowest mean {best['scored_by']}, {best['score']:.4g} sr^-1, "
               f"of {len(ranked)} candidates{runner_up}")
        log.info("node %r: %s", ctx.node, why)
        winner = ctx.inputs[port]
        attrs = {k: v for k, v in winner.attrs.items()
                 if k not in ("kind", "version", "token", "complete", "provenance", "run", "summary")}
        attrs["selection"] = {"chosen": port, "why": why, "by": by, "candidates": table}
        summary = dict(winner.attrs.get("summary", {}))
        return Output(arrays={name: winner.array(name) for name in winner.names()}, attrs=attrs,
                      finalize=lambda art: {"summary": summary})
