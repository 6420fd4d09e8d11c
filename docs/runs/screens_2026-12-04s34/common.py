"""Shared set-up of the session-34 analysis scripts (run with exec, next to them): the scene, the trained model, its
renders and the training photos with their rendered depths. argv: DATA_DIR TRAIN_VIEWS PLY."""
import numpy as np, torch, sys
from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io import load_scene
from gsgs_engine.io.ply import read_gaussian_ply
from gsgs_engine.io.world_scale import ply_to_internal
from gsgs_engine.priors.warp_inpaint import TrainingPhoto, surface_depth, warp_photos
from gsgs_engine.render import render
data, nviews, ply = sys.argv[1], int(sys.argv[2]), sys.argv[3]
scene = load_scene(data, train_views=nviews)
model = GaussianModel.from_ply(ply_to_internal(read_gaussian_ply(ply), scene.world_scale))
bg = torch.as_tensor(scene.background, dtype=torch.float32)
deg = model.max_sh_degree


@torch.no_grad()
def render_at(cam):
    return render(model.means, model.quats, model.scales, model.opacities, model.sh(deg), cam, sh_degree=deg,
                  background=bg, backend="cpu")


def img(view):
    return torch.from_numpy(np.ascontiguousarray(view.image(), dtype=np.float32))


photos = []
for v in scene.train:
    o = render_at(v.camera)
    photos.append(TrainingPhoto(v.camera, img(v), surface_depth(o.depth, o.alpha)))
