"""Training of the T-Net (shape orientation for matching, reference-spec §1.6) on procedural shapes.

``litege train tnet --config configs/tnet-quadrupeds.toml [--out DIR]`` runs
:func:`run_tnet_training`:

1. **Shapes.** Shape ``k`` of a split is ``generate_shape(category, families[k % n], offset + k)``
   with the offsets of :data:`~litege_core.datasets.spec.SPLIT_SEED_OFFSETS` (train 0…,
   val 1,000,000…), generated once and kept in memory. Each is brought into the canonical frame:
   the template orientation, centred on the mean of 8000 area-weighted samples and scaled to unit
   area (:func:`~litege_core.canonical.canonicalize_unit_area` with the identity rotation).
   With ``data.extra_category`` the posed meshes of a collection source (MakeHuman bodies,
   rigged animals: the shapes of ``litege data build --category SOURCE``, same seeds) follow
   in both splits, canonical in the same way (:func:`training_shape_sets`). With
   ``data.steep_share`` that share of the procedural shapes rears, leaps, sits up or lies
   on the belly instead (:func:`~litege_core.synth.poses.steep_pose`), still in the ground
   frame of the template.
2. **Batches.** Every step draws ``batch_size`` shapes, one point count ``n`` per batch
   (log-uniform in ``[min_points, max_points]``: 500-point clouds up to the 2000 points
   :func:`predict_rotation` feeds) and, per item, ``n`` fresh area-weighted samples. Items are
   augmented so one network serves every input kind: with ``broken_probability`` a fraction of
   the faces is removed before sampling (broken meshes), with ``noise_probability`` Gaussian noise
   is added (σ uniform up to ``noise_sigma``, unit-area units), each cloud is re-centred on its own
   mean and rescaled by a log-uniform factor in ``[scale_min, scale_max]`` (the Poisson-spacing
   scale of point clouds and broken meshes is not exactly the unit-area scale: with the paper's
   constants and our sampler a 40 %-broken mesh comes out about 1.33× larger). A uniform rotation
   ``R_gt`` (``scipy Rotation.random``) per item gives ``pc_rot = pc_canon @ R_gtᵀ``; the loss is
   :func:`~litege_core.nets.tnet_loss` (angle + λ·point, λ = 2). Step ``t`` draws everything from
   ``default_rng([seed, 1, t])``, so a run is a pure function of its config.
3. **Network.** :class:`~litege_core.nets.TNet` with the ``[network]`` widths and pre-alignment:
   ``prealign = "pca"`` makes the network regress only the residual rotation of the PCA-aligned
   cloud (same :meth:`~litege_core.nets.TNet.rotation` contract), which is what makes a CPU
   budget of about a thousand steps enough; ``"none"`` is the reference T-Net.
4. **Optimization.** Adam, learning rate cosine from ``lr`` to ``eta_min`` over all steps; every
   ``val_every`` steps the mean angle on a FIXED validation set (each val shape as a 2000-sample
   mesh, a 500-point cloud and a 40 %-broken mesh, fixed rotations and samples) is measured; the
   best weights by that mean are kept and written to ``RUN/tnet.safetensors``.
5. **Report** (``RUN/report.json``) with the best weights: the alignment-error distribution on
   the training shapes (one random rotation each, ``default_rng(20)`` as the reference's
   ``np.random.seed(20)``; the indices above 0.66 rad are the rejection filter of spec §1.6),
   on the val shapes as meshes, as 500-point clouds and as broken meshes, the last two scaled as
   at inference (:func:`~litege_core.canonical.canonicalize_poisson` with the §1.4 settings).

The weights file holds the :func:`~litege_core.nets.state_to_tensors` tensors and, in its
safetensors metadata, ``format = "litege-tnet"``, the network ``config`` and a ``training``
summary; :func:`load_tnet` reads it back, :func:`predict_rotation` applies it to one cloud.
"""

from __future__ import annotations

from litege_core.train.tnet.batches import (
    BatchLoader,
    TNetBatch,
    ValidationSet,
    sample_batch,
    validation_set,
)
from litege_core.train.tnet.config import (
    FAILURE_THRESHOLD,
    TNetAugmentConfig,
    TNetDataConfig,
    TNetNetworkConfig,
    TNetOptimConfig,
    TNetOutputConfig,
    TNetReportConfig,
    TNetTrainConfig,
    load_tnet_config,
)
from litege_core.train.tnet.evaluation import (
    alignment_report,
    angle_statistics,
    batch_angles,
    validate,
)
from litege_core.train.tnet.shapes import ShapeSet, canonical_shape_set, generate_shape_set
from litege_core.train.tnet.training import (
    TNetRunResult,
    cosine_lr,
    run_tnet_training,
    train_step,
    train_tnet,
)
from litege_core.train.tnet.weights import (
    PREDICT_MAX_POINTS,
    TNET_FORMAT,
    load_tnet,
    predict_rotation,
    read_tnet_metadata,
    save_tnet,
    start_from,
)

__all__ = [
    "FAILURE_THRESHOLD",
    "PREDICT_MAX_POINTS",
    "TNET_FORMAT",
    "BatchLoader",
    "ShapeSet",
    "TNetAugmentConfig",
    "TNetBatch",
    "TNetDataConfig",
    "TNetNetworkConfig",
    "TNetOptimConfig",
    "TNetOutputConfig",
    "TNetReportConfig",
    "TNetRunResult",
    "TNetTrainConfig",
    "ValidationSet",
    "alignment_report",
    "angle_statistics",
    "batch_angles",
    "canonical_shape_set",
    "cosine_lr",
    "generate_shape_set",
    "load_tnet",
    "load_tnet_config",
    "predict_rotation",
    "read_tnet_metadata",
    "run_tnet_training",
    "sample_batch",
    "save_tnet",
    "start_from",
    "train_step",
    "train_tnet",
    "validate",
    "validation_set",
]
