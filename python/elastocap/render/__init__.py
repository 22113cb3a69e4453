"""Drawing meshes into cameras: projection, silhouettes, shaded images, the rasteriser.

A low layer (cameras and numpy only), used by pictures, reports, stages and algorithms
(the model-based silhouettes) alike; the synthetic captures draw their scenes with it.
"""

from elastocap.render.mesh import project_mesh, render_image, render_mesh, render_silhouette

__all__ = ["project_mesh", "render_image", "render_mesh", "render_silhouette"]
