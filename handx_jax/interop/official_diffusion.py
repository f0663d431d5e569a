"""The released HandX diffusion checkpoints (``model.pt`` + ``config.yaml``) ⇄ diffusion run folders.

The official model (``MotionDiffusionModel``, arch ``trans_dec_treble_residual``, reference §3.1) and
``models.dit.TrebleDenoiser`` are the same network; the state dict maps onto our tree one to one:

    official state_dict                                   ours (params["params"])
    input_process.pose_embedding.{weight,bias}            input_proj          Linear(168 → D)
    embed_timestep.time_embedding.{0,2}.{weight,bias}     time_mlp_1, _2      Linear → SiLU → Linear on PE[t]
    text_embedding_project.{weight,bias}                  text_proj           Linear(T5 width → D)
    {left_hand,right_hand,two_hands_relation}_cls_token   cls (3, D)          the three branch tokens
    null_text_embedding (1, 1, D)                         null_text (D,)      classifier-free null text
    seq_trans_decoder.layers.i.*                          layer{i}            the ONE decoder of the 3 branches
    output_process.pose_head.{weight,bias}                output_proj         Linear(D → 168)
    sequence_pos_encoder.pe (1, 5000, D),                 (models.layers.sinusoidal_table, not parameters;
    embed_timestep.positional_encode (5000, D)             checked against it on import, written on export)

The frozen ``_text_model.*`` (T5) is not in a released checkpoint (reference §3.6): the encoder comes
from ``--encoder``. The number of heads is in no tensor's shape: it comes from ``config.yaml``
(``model.num_heads``) or ``--heads``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from handx_jax.interop import torch_layers as tl
from handx_jax.interop import torch_pickle
from handx_jax.infra.atomic import atomic_write_text
from handx_jax.infra.checksums import sha256_file as sha256
from handx_jax.infra.errors import DataError
from handx_jax.infra.outputs import exclusive_output, refuse_existing
from handx_jax.config import to_dict
from handx_jax.models.dit import DiTConfig, sinusoidal_table, size_name

ARCH = "trans_dec_treble_residual"
CLS_NAMES = ("left_hand_cls_token", "right_hand_cls_token", "two_hands_relation_cls_token")  # branch order L, R, I
DECODER = "seq_trans_decoder.layers"
PE_NAMES = ("sequence_pos_encoder.pe", "embed_timestep.positional_encode")
# The released weights' licence (the HandX model card on the Hugging Face hub), recorded in every imported run.
LICENCE = "CC-BY-NC-4.0 (HandX released weights: non-commercial use, attribution)"
# The official PE is computed in float32 by PyTorch; ours in float64 then rounded. They differ by float32
# rounding of the angle (≤ ~5e-4 at position 5000); a larger gap means another table.
PE_TOLERANCE = 2e-3


# --------------------------------------------------------------------------------------------------
# Names both ways


def params_from_official(sd: Mapping[str, Any], cfg: DiTConfig, *, path=None) -> dict:
    """The official state dict → our ``{"params": …}`` tree for ``cfg``."""
    D, H, F, Dt, M = cfg.dim, cfg.heads, cfg.ff, cfg.text_dim, cfg.motion_features
    p = {
        "input_proj": tl.linear_from(sd, "input_process.pose_embedding", M, D, path=path),
        "time_mlp_1": tl.linear_from(sd, "embed_timestep.time_embedding.0", D, D, path=path),
        "time_mlp_2": tl.linear_from(sd, "embed_timestep.time_embedding.2", D, D, path=path),
        "text_proj": tl.linear_from(sd, "text_embedding_project", Dt, D, path=path),
        "output_proj": tl.linear_from(sd, "output_process.pose_head", D, M, path=path),
        "cls": np.stack([tl.tensor(sd, n, (1, 1, D), path=path).reshape(D) for n in CLS_NAMES]),
        "null_text": tl.tensor(sd, "null_text_embedding", (1, 1, D), path=path).reshape(D).copy(),
    }
    for i in range(cfg.layers):
        p[f"layer{i}"] = tl.decoder_layer_from(sd, f"{DECODER}.{i}", D, H, F, path=path)
    return {"params": p}


def official_from_params(params: Mapping[str, Any], cfg: DiTConfig) -> dict[str, np.ndarray]:
    """Our tree → the official state dict (float32, the official key order), sinusoid buffers included."""
    p = {k: _np(v) for k, v in params["params"].items()}
    D = cfg.dim
    pe = sinusoidal_table(cfg.max_len, D)
    sd = {"null_text_embedding": p["null_text"].reshape(1, 1, D).copy()}
    sd.update({n: p["cls"][k].reshape(1, 1, D).copy() for k, n in enumerate(CLS_NAMES)})
    sd.update(tl.linear_to(p["input_proj"], "input_process.pose_embedding"))
    sd["sequence_pos_encoder.pe"] = pe[None].copy()
    sd.update(tl.linear_to(p["text_proj"], "text_embedding_project"))
    for i in range(cfg.layers):
        sd.update(tl.decoder_layer_to(p[f"layer{i}"], f"{DECODER}.{i}"))
    sd["embed_timestep.positional_encode"] = pe
    sd.update(tl.linear_to(p["time_mlp_1"], "embed_timestep.time_embedding.0"))
    sd.update(tl.linear_to(p["time_mlp_2"], "embed_timestep.time_embedding.2"))
    sd.update(tl.linear_to(p["output_proj"], "output_process.pose_head"))
    return {k: np.ascontiguousarray(v, np.float32) for k, v in sd.items()}


def _np(tree):
    if isinstance(tree, Mapping):
        return {k: _np(v) for k, v in tree.items()}
    return np.asarray(tree)


# --------------------------------------------------------------------------------------------------
# Reading a released checkpoint


MODEL_KEYS = ("latent_dim", "layers", "num_heads", "ff_size", "dropout", "activation", "arch")


def read_config_yaml(path: str | os.PathLike) -> dict:
    """The ``model:`` section of an official Hydra ``config.yaml`` (or the file itself if it is that section:
    model keys at the top level); a file with neither is refused, naming what it holds."""
    import yaml

    try:
        doc = yaml.safe_load(Path(path).read_text())
    except IsADirectoryError:
        raise DataError("is a directory; --config names the official config.yaml file", path=path) from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        raise DataError(f"cannot read the config ({e})", path=path) from None
    if not isinstance(doc, dict):
        raise DataError("config.yaml is not a mapping", path=path)
    model = doc.get("model", doc)
    if not isinstance(model, dict):
        raise DataError("config.yaml's 'model' is not a mapping", path=path)
    if "model" not in doc and not any(k in doc for k in MODEL_KEYS):
        raise DataError(f"no 'model:' section (top-level keys: {sorted(map(str, doc))[:8]}); the official "
                        f"config.yaml has model: with {', '.join(MODEL_KEYS[:4])}", path=path)
    return model


def read_state_dict(path: str | os.PathLike) -> dict[str, Any]:
    """The state dict of an official ``model.pt`` (``{"state_dict": …}``, or a bare state dict)."""
    obj = torch_pickle.load(path)
    if isinstance(obj, dict) and isinstance(obj.get("state_dict"), dict):
        sd = obj["state_dict"]
    elif isinstance(obj, dict) and obj and all(isinstance(v, np.ndarray) for v in obj.values()):
        sd = obj  # a bare state dict
    else:
        if isinstance(obj, dict):
            held = [f"{k!r} ({len(v)} tensors)" if isinstance(v, dict) and any(isinstance(x, np.ndarray)
                    for x in v.values()) else repr(k) for k, v in list(obj.items())[:6]]
            what = f"a dict of {', '.join(held)}" if held else "an empty dict"
        else:
            what = f"a {type(obj).__name__}"
        raise DataError(f"no state dict in the checkpoint: it holds {what}; expected the official "
                        "{'state_dict': {name: tensor}} (or a bare {name: tensor})", path=path)
    if not sd:
        raise DataError("the checkpoint's state dict is empty", path=path)
    return {k[len("module."):] if k.startswith("module.") else k: v for k, v in sd.items()}


# Where the width D shows in the tensors' shapes (name, axis): each of them must agree, so that a single
# damaged tensor is named as the odd one out rather than every correct tensor being checked against it.
WIDTH_AXES = (("null_text_embedding", -1), *((n, -1) for n in CLS_NAMES), ("input_process.pose_embedding.weight", 0),
              ("text_embedding_project.weight", 0), ("output_process.pose_head.weight", 1),
              ("embed_timestep.time_embedding.0.weight", 0), ("embed_timestep.time_embedding.2.weight", 0))


def _agreed(sd: Mapping[str, Any], axes, what: str, *, path=None) -> tuple[int, str]:
    """The size the tensors ``axes`` agree on, and a note of where it comes from; a tensor that disagrees
    with the others is refused by name."""
    seen = {}
    for name, ax in axes:
        a = sd.get(name)
        if isinstance(a, np.ndarray) and a.ndim >= (ax + 1 if ax >= 0 else -ax):
            seen[name] = int(a.shape[ax])
    if not seen:
        tl.tensor(sd, axes[0][0], path=path)  # the missing tensor's own refusal
    values = [v for v in seen.values()]
    size = max(set(values), key=values.count)
    odd = [n for n, v in seen.items() if v != size]
    if odd:
        agree = [n for n, v in seen.items() if v == size]
        raise DataError(f"tensor {odd[0]!r} has shape {tuple(sd[odd[0]].shape)}: {what} {seen[odd[0]]}, but "
                        f"{len(agree)} other tensor(s) ({agree[0]}, …) have {what} {size}", path=path)
    return size, f"{what} {size} from {len(seen)} tensors' shapes"


def infer_config(sd: Mapping[str, Any], *, heads: int | None, yaml_model: dict | None, path=None,
                 config_path=None) -> DiTConfig:
    """Sizes from the tensors' shapes, checked against ``config.yaml``'s ``model:`` keys when given; the
    head count from the config or ``heads`` (no shape reveals it). Every refusal names its source: the
    tensor, ``config.yaml`` or ``--heads``."""
    from handx_jax.interop import checks

    D, _ = _agreed(sd, WIDTH_AXES, "width", path=path)
    L = tl.layer_count(sd, DECODER)
    if L == 0:
        raise DataError(f"no decoder layers ({DECODER}.0.…): not a {ARCH} checkpoint", path=path)
    F, _ = _agreed(sd, [(f"{DECODER}.{i}.linear1.weight", 0) for i in range(L)]
                   + [(f"{DECODER}.{i}.linear2.weight", 1) for i in range(L)], "FF size", path=path)
    Dt = tl.tensor(sd, "text_embedding_project.weight", path=path).shape[1]
    M = tl.tensor(sd, "input_process.pose_embedding.weight", path=path).shape[1]
    if M != 42 * 4:
        raise DataError(f"input_process.pose_embedding takes {M} features per frame; HandX's is 42 joints x 4 = 168",
                        path=path)
    ym = yaml_model or {}
    if yaml_model is not None:
        arch = ym.get("arch", ARCH)
        if arch != ARCH:
            raise DataError(f"model.arch is {arch!r}; only {ARCH!r} is supported", path=config_path)
        act = ym.get("activation", "gelu")
        if act != "gelu":
            raise DataError(f"model.activation is {act!r}; the denoiser uses gelu", path=config_path)
        for key, got in (("latent_dim", D), ("layers", L), ("ff_size", F)):
            if key in ym and checks.whole(ym[key], f"model.{key}", path=config_path) != got:
                raise DataError(f"model.{key} is {ym[key]} but the checkpoint's tensors have {got}", path=config_path)
    h_cfg = ym.get("num_heads")
    if h_cfg is not None:
        h_cfg = checks.whole(h_cfg, "model.num_heads", path=config_path)
    if heads is not None:
        heads = checks.whole(heads, "--heads")
        if h_cfg is not None and h_cfg != heads:
            raise DataError(f"--heads {heads} contradicts model.num_heads {h_cfg}", path=config_path)
    if heads is None and h_cfg is None:
        if yaml_model is not None:
            raise DataError("no model.num_heads, and the number of heads is in no tensor's shape: add it to the "
                            "config's model: section, or give --heads N", path=config_path)
        raise DataError("the number of heads is in no tensor's shape: give --config config.yaml (model.num_heads) "
                        "or --heads N", path=path)
    H = heads if heads is not None else h_cfg
    if D % H:
        src, where = ("--heads", None) if heads is not None else ("model.num_heads", config_path)
        raise DataError(f"{src} {H} does not divide the width {D} (the tensors' shapes): each head takes D / H "
                        "values", path=where)
    try:
        dropout = float(ym.get("dropout", 0.1))
    except (TypeError, ValueError):
        raise DataError(f"model.dropout is {ym.get('dropout')!r}, not a number", path=config_path) from None
    return DiTConfig(layers=L, dim=D, heads=H, ff=F, dropout=dropout, text_dim=Dt)


def check_tables(sd: Mapping[str, Any], cfg: DiTConfig, *, path=None) -> float:
    """The checkpoint's sinusoid buffers against ours: the max |difference| (refused above tolerance)."""
    ours = sinusoidal_table(cfg.max_len, cfg.dim)
    worst = 0.0
    for name in PE_NAMES:
        if name not in sd:
            continue
        a = tl.tensor(sd, name, path=path).reshape(-1, cfg.dim)
        n = min(len(a), len(ours))
        gap = float(np.max(np.abs(a[:n] - ours[:n])))
        if gap > PE_TOLERANCE:
            raise DataError(f"{name} differs from the sinusoidal table by {gap:.2e} (> {PE_TOLERANCE}): another "
                            "positional encoding than the official model's", path=path)
        worst = max(worst, gap)
    return worst


def unused_tensors(sd: Mapping[str, Any], cfg: DiTConfig) -> list[str]:
    known = set(official_from_params(_zeros_like_tree(cfg), cfg))
    return sorted(k for k in sd if k not in known and not k.startswith("_text_model."))


def _zeros_like_tree(cfg: DiTConfig) -> dict:
    import jax

    from handx_jax.models.dit import init_denoiser

    shapes = jax.eval_shape(lambda r: init_denoiser(cfg, r)[1], jax.random.PRNGKey(0))
    return jax.tree_util.tree_map(lambda s: np.zeros(s.shape, np.float32), shapes)




# --------------------------------------------------------------------------------------------------
# Normalisation statistics


def read_stats(*, data: str | os.PathLike | None = None, stats: str | os.PathLike | None = None):
    """The diffusion (42, 4) mean/std as :class:`~handx_jax.representation.NormStats`.

    ``data``: a handx-jax dataset; its ``stats.npz`` holds them computed as the official loader does
    (reference §1.8: train split, per-clip wrist-midpoint centring, float64 moments over every frame,
    std < 1e-4 → 1; the official loader weights a clip by its number of annotations, which is the same
    for every clip of a handx-jax dataset). ``stats``: an official ``mean_std_joint_pos_w_scalar_rot/``
    folder (``mean.npy``, ``std.npy``), a ``.npz`` with ``mean``/``std`` or ``diffusion_mean``/``diffusion_std``
    (a run's ``norm_stats.npz``, a dataset's ``stats.npz``)."""
    from handx_jax import representation as rep

    if (data is None) == (stats is None):
        raise DataError("give exactly one of --data DATASET or --stats FILE for the normalisation statistics")
    if data is not None:
        from handx_jax.dataset.format import Dataset

        ds = Dataset.open(data)
        return rep.NormStats.from_npz_dict(ds.stats, "diffusion", path=ds.root / "stats.npz")
    from handx_jax.interop import checks

    p = Path(stats)
    mean_path = std_path = p
    if p.is_dir():
        mean_path, std_path = p / "mean.npy", p / "std.npy"
        mean, std = checks.load_array_file(mean_path), checks.load_array_file(std_path)
    else:
        d = checks.load_array_file(p, npz=True)
        if not isinstance(d, dict):
            raise DataError("an .npy array; --stats takes a folder with mean.npy and std.npy, or an .npz with "
                            "mean/std", path=p)
        names = ("diffusion_mean", "diffusion_std") if "diffusion_mean" in d else ("mean", "std")
        if any(n not in d for n in names):
            raise DataError(f"no {names[0]}/{names[1]} arrays (it holds {sorted(d)[:6]})", path=p)
        mean, std = d[names[0]], d[names[1]]
    mean, std = np.asarray(mean, np.float32).reshape(-1), np.asarray(std, np.float32).reshape(-1)
    if mean.size != 168 or std.size != 168:
        raise DataError(f"mean/std have {mean.size}/{std.size} values; the diffusion features have 42 x 4 = 168",
                        path=p)
    checks.norm_stats(mean, std, mean_path=mean_path, std_path=std_path)
    if not p.is_dir() and "diffusion_mean" in d:  # a run's norm_stats.npz or a dataset's stats.npz: its eps too
        return rep.NormStats.from_npz_dict(d, "diffusion", path=p)
    return rep.NormStats(mean=mean.reshape(42, 4), std=std.reshape(42, 4))


# --------------------------------------------------------------------------------------------------
# Import: a run folder of the diffusion family


def import_checkpoint(model_pt: str | os.PathLike, out: str | os.PathLike, *, encoder: str | os.PathLike,
                      config: str | os.PathLike | None = None, heads: int | None = None,
                      data: str | os.PathLike | None = None, stats: str | os.PathLike | None = None,
                      overwrite: bool = False, licence: str = LICENCE) -> dict:
    """Write ``out``, a diffusion run folder holding the official checkpoint's weights, that
    ``handx generate --run out`` and the family's ``load`` use unchanged. Returns a summary."""
    import orbax.checkpoint as ocp

    from handx_jax.families import get_family
    from handx_jax.infra.atomic import atomic_dir, atomic_write_json
    from handx_jax.infra.checksums import write_tree_checksum
    from handx_jax.text.hf import as_encoder

    from handx_jax.interop import checks
    from handx_jax.infra.diskspace import check_free_space
    from handx_jax.infra.quiet import library_output_held

    fam = get_family("diffusion")
    refuse_existing(out, overwrite=overwrite)  # at once, not after reading the weights
    model_pt = Path(model_pt)
    sd = read_state_dict(model_pt)
    ym = read_config_yaml(config) if config is not None else None
    cfg_m = infer_config(sd, heads=heads, yaml_model=ym, path=model_pt, config_path=config)
    heads_from = "--heads" if heads is not None else "config.yaml's model.num_heads"
    with checks.sizes_from(f"width {cfg_m.dim} and FF {cfg_m.ff} agreed by the tensors' shapes, "
                           f"{cfg_m.heads} heads from {heads_from}"):
        pe_gap = check_tables(sd, cfg_m, path=model_pt)
        params = params_from_official(sd, cfg_m, path=model_pt)
    unused = unused_tensors(sd, cfg_m)
    if unused:
        raise DataError(f"{len(unused)} tensor(s) this importer does not know, e.g. {unused[:3]} (another "
                        "architecture?)", path=model_pt)
    norm = read_stats(data=data, stats=stats)
    enc = as_encoder(encoder)
    if enc.cfg.d_model != cfg_m.text_dim:
        raise DataError(f"the encoder's width is {enc.cfg.d_model} but text_embedding_project takes {cfg_m.text_dim} "
                        "(t5-base: 768)", path=enc.path or encoder)
    run_cfg = fam.make_config("tiny", encoder=str(enc.path) if enc.path else "")
    # No EMA (the file holds one set of weights); float32 text so the projected prompts equal the official
    # model's (the runs trained here round them through their float16 cache).
    # Captions up to 128 tokens (the project's default; the official tokenizer truncates at 512, far above
    # HandX's captions).
    run_cfg = dataclasses.replace(
        run_cfg, model=cfg_m, preset=size_name(cfg_m),
        train=dataclasses.replace(run_cfg.train, steps=0, ema_decay=0.0),
        data=dataclasses.replace(run_cfg.data, cache_dtype="float32"))
    numbers = fam.numbers(run_cfg, encoder_cfg=enc.cfg)
    record = {
        "family": fam.FAMILY, **to_dict(run_cfg), "data_fraction": 1.0, **numbers,
        "text_cache": {"encoder_fingerprint": enc.fingerprint, "d_model": enc.cfg.d_model},
        "source": {"format": "official HandX diffusion checkpoint (trans_dec_treble_residual)",
                   "file": str(model_pt.absolute()), "sha256": sha256(model_pt),
                   "config": str(Path(config).absolute()) if config else None, "heads_from": "config.yaml"
                   if heads is None else "--heads", "licence": licence, "pe_max_abs_diff": pe_gap},
    }
    out = Path(out)
    with atomic_dir(out, overwrite=overwrite) as tmp:
        atomic_write_json(tmp / "config.json", record)
        np.savez(tmp / fam.NORM_FILE, **norm.to_npz_dict("diffusion"))
        # JAX arrays, as the train loop saves them: orbax restores the types it saved, and NumPy parameters
        # would be copied to the devices again on every sampler call.
        import jax
        import jax.numpy as jnp

        state = {"params": jax.tree_util.tree_map(jnp.asarray, params), "opt_state": {}, "ema": {},
                 "step": jnp.zeros((), jnp.int32)}
        # orbax needs about the weights' bytes; a full disk is one line naming --out (atomic_dir), and what orbax
        # and tensorstore print while failing is held back (library_output_held).
        check_free_space(tmp / "checkpoints", 2 * sum(a.nbytes for a in jax.tree_util.tree_leaves(params)))
        with library_output_held():
            mngr = ocp.CheckpointManager((tmp / "checkpoints").absolute(), options=ocp.CheckpointManagerOptions(
                create=True, enable_async_checkpointing=False))
            try:
                mngr.save(0, args=ocp.args.StandardSave(state))
                mngr.wait_until_finished()
            finally:  # a failed save (a full disk) too: close() joins orbax's threads, which would otherwise
                with contextlib.suppress(Exception):  # go on writing into the folder atomic_dir is removing
                    mngr.close()
        write_tree_checksum(tmp / "checkpoints" / "0")
    return {"run": str(out), "model": dataclasses.asdict(cfg_m), "params": numbers["params"],
            "sha256": record["source"]["sha256"], "pe_max_abs_diff": pe_gap}


# --------------------------------------------------------------------------------------------------
# Export: a run → an official-format checkpoint


CONFIG_TEMPLATE = """\
model:
  latent_dim: {dim}
  layers: {layers}
  num_heads: {heads}
  ff_size: {ff}
  dropout: {dropout}
  activation: gelu
  cond_mode: text
  text_model: t5-base
  max_text_length: null
  arch: trans_dec_treble_residual
  cond_mask_prob: {cond_drop}
  treble_mask_prob: 1.0
"""


def _export_targets(out, config, stats, overwrite: bool) -> list[tuple[str, Path]]:
    """Every file ``export`` writes, each named by its flag, checked before anything is read or written: an
    existing one is refused without ``--force``, a directory where a file goes (or a file where the
    ``--stats`` folder goes) names the flag."""
    targets = [("--out", Path(out))]
    if config:
        targets.append(("--config", Path(config)))
    if stats:
        s = Path(stats)
        if s.exists() and not s.is_dir():
            raise DataError(f"--stats {s} is a file; it names the folder to write mean.npy and std.npy into")
        targets += [("--stats", s / "mean.npy"), ("--stats", s / "std.npy")]
    for flag, p in targets:
        if p.is_dir():
            raise DataError(f"{flag} {p} is a directory; it names the {p.name if flag == '--stats' else 'file'} "
                            "to write")
        refuse_existing(p, overwrite=overwrite, flag=flag)
    return targets


def export_run(run_dir: str | os.PathLike, out: str | os.PathLike, *, config: str | os.PathLike | None = None,
               stats: str | os.PathLike | None = None, ema: bool = True, overwrite: bool = False) -> dict:
    """Write the run's weights as an official ``model.pt`` (``{"state_dict": …}``, ``_text_model.*`` left
    out as the official training loop saves it), and optionally its ``config.yaml`` and statistics. Returns
    what was written and what the official format does not carry (``dropped``).

    All or nothing: every output is checked first (``_export_targets``) and held (``infra.outputs.exclusive_output``:
    a second export to the same file is refused), each is written atomically, and if one fails the ones
    already written are removed again."""
    from handx_jax.families import get_family, run_config
    from handx_jax.interop import checks
    from handx_jax.infra.atomic import atomic_save_npy
    from handx_jax.train import load_params

    targets = _export_targets(out, config, stats, overwrite)
    fam = get_family("diffusion")
    doc = run_config(run_dir, fam.FAMILY)
    cfg = fam.config_from_dict(doc)
    m = cfg.model
    if (m.joints, m.channels) != (42, 4):
        raise DataError(f"the run's motion is {m.joints} x {m.channels} per frame; the official model's is 42 x 4",
                        path=run_dir)
    params, step = load_params(run_dir, ema=ema)
    sd = official_from_params(params, m)
    for k, v in sd.items():  # load_params refuses NaN too; the names here are the official ones
        checks.finite(k, v, path=Path(run_dir) / "checkpoints" / str(step))
    used_ema = bool(ema and cfg.train.ema_decay > 0)
    dropped = [
        f"the frozen text encoder (the official loader rebuilds T5 itself; this run used {cfg.data.encoder or '?'}: "
        f"d_model {m.text_dim}{'' if m.text_dim == 768 else ', not t5-base' + chr(39) + 's 768'})",
        "the normalisation statistics (the official loader reads data_dir/mean_std_joint_pos_w_scalar_rot/"
        "{mean,std}.npy" + (f"; written to {stats}" if stats else "; pass --stats DIR to write them") + ")",
        f"the training recipe (joint_drop {cfg.diffusion.joint_drop}: the official training drops branches only "
        "independently) and the sampler settings (guidance, masks), which the official code takes from its own config",
    ]
    if cfg.train.ema_decay > 0:
        dropped.insert(2, f"the run's {'raw' if used_ema else 'EMA'} weights (exported: the "
                          f"{'EMA' if used_ema else 'raw'} ones, step {step})")
    norm = None
    if stats:
        from handx_jax import representation as rep

        norm = rep.NormStats.read(Path(run_dir) / fam.NORM_FILE, "diffusion")
    written: list[Path] = []
    with contextlib.ExitStack() as held:
        for flag, p in targets:
            held.enter_context(exclusive_output(p, overwrite=overwrite, flag=flag))
        try:
            written.append(torch_pickle.save(out, {"state_dict": sd}))
            if norm is not None:
                written.append(atomic_save_npy(Path(stats) / "mean.npy", norm.mean))
                written.append(atomic_save_npy(Path(stats) / "std.npy", norm.std))
            if config:
                written.append(atomic_write_text(config, CONFIG_TEMPLATE.format(
                    dim=m.dim, layers=m.layers, heads=m.heads, ff=m.ff, dropout=m.dropout,
                    cond_drop=cfg.diffusion.cond_drop)))
        except BaseException:
            for p in written:  # nothing half-written: all of the export or none of it
                with contextlib.suppress(OSError):
                    p.unlink()
            raise
    return {"out": str(out), "tensors": len(sd), "step": step, "ema": used_ema, "dropped": dropped,
            "model": dataclasses.asdict(m)}
