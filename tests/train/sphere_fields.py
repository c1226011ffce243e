"""Grid fields at their initial sphere, with a chosen beta: the renderer's tests' worked object."""
import math

import torch

from srvol.fields import FieldConfig, SceneFields


def sphere_fields(radius: float, beta: float) -> SceneFields:
    """Small grid fields whose SDF is the initial sphere of ``radius`` (the learned residual is zero)."""
    f = SceneFields(FieldConfig(kind="grid", sdf_levels=(8,), mat_levels=2, mat_max_res=32, mat_table_log2=12,
                                init_radius=radius), learn_intensity=False)
    with torch.no_grad():
        f.log_beta.fill_(math.log(beta))
    return f
