"""UDF-PCA shape descriptor (reference spec §2): grid, occupancy, informative voxels, UDF, PCA.

Pipeline::

    grid = VoxelGrid()                                   # 121³ at pitch 0.02, [−1.2, 1.2]³
    stats = OccupancyStatistics(grid)                    # streamed over training meshes
    stats.add(mesh_occupancy(vertices, faces, grid))
    voxels = stats.select(std_threshold=0.14)            # sorted flat indices
    udf = UdfEvaluator(grid.centers(voxels))(clouds)     # (B, M) nearest-sample distances
    pca = fit_pca_streamed(chunks, n_components=400)     # randomized SVD over row chunks
    basis = UdfPcaBasis.from_pca(grid, voxels, pca)      # frozen, safetensors save/load
    z = basis.describe(points)                           # (k,) = (udf − μ)Pᵀ

or all at once: :func:`fit_basis`.
"""

from litege_core.descriptor.basis import DescriptorEngine, DescriptorResult, UdfPcaBasis
from litege_core.descriptor.fit import fit_basis
from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.informative import (
    OccupancyStatistics,
    frequency_band,
    std_to_variance,
    variance_to_std,
)
from litege_core.descriptor.occupancy import (
    mesh_inside,
    mesh_occupancy,
    mesh_surface_voxels,
    point_cloud_occupancy,
)
from litege_core.descriptor.pca import (
    PcaResult,
    explained_variance_curve,
    fit_pca_exact,
    fit_pca_streamed,
)
from litege_core.descriptor.udf import UdfBackend, UdfEvaluator, compute_udf

__all__ = [
    "DescriptorEngine",
    "DescriptorResult",
    "OccupancyStatistics",
    "PcaResult",
    "UdfBackend",
    "UdfEvaluator",
    "UdfPcaBasis",
    "VoxelGrid",
    "compute_udf",
    "explained_variance_curve",
    "fit_basis",
    "fit_pca_exact",
    "fit_pca_streamed",
    "frequency_band",
    "mesh_inside",
    "mesh_occupancy",
    "mesh_surface_voxels",
    "point_cloud_occupancy",
    "std_to_variance",
    "variance_to_std",
]
