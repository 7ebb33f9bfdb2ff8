"""Policy files written by the code before the method menu (commit d6cafd7): one pair per method row."""
import torch, numpy as np
from safetensors.torch import save_file
from ps_ray.nets.modular import METHODS, NetDims, update_normalizers
from ps_ray.nets.sac import build_sac_nets
from ps_ray.weights import save_policy, signature_of
from ps_ray.stitch import stitch_policies

torch.manual_seed(0)
dims = NetDims(6, 8, 7)
D, H = 8, 16
anchors = np.random.default_rng(0).normal(size=(D, dims.task_dim)).astype(np.float32)
out = "tests/data/policies_v1"
B = 5
g = torch.Generator().manual_seed(1)
task_in, robot_in = torch.randn(B, 6, generator=g), torch.randn(B, 8, generator=g)
action = torch.rand(B, 7, generator=g) * 2 - 1
expected = {"task_in": task_in, "robot_in": robot_in, "action": action}
for name, spec in METHODS.items():
    paths = []
    for seed in (0, 1):
        torch.manual_seed(100 * seed + len(name))
        nets = build_sac_nets(name, dims, interface_dim=D, hidden=H, anchors=anchors if spec.relative else None)
        with torch.no_grad():
            for p in nets.parameters():
                p.add_(torch.randn_like(p) * 0.3)
        update_normalizers(nets.actor, torch.randn(32, 6) * 2 + 1, torch.randn(32, 8) * 0.5)
        for crit in (nets.critic, nets.critic_twin, nets.target_critic, nets.target_critic_twin):
            update_normalizers(crit, torch.randn(32, 6) * 2 + 1, torch.randn(32, 8) * 0.5)
        if spec.defer_relative:
            nets.actor.task.switch_relative_on()
        path = f"{out}/{name}_{seed}.safetensors"
        save_policy(path, nets, signature_of(nets, name, D, H))
        paths.append(path)
        with torch.no_grad():
            mean, log_std = nets.actor(task_in, robot_in)
            expected[f"{name}_{seed}.mean"], expected[f"{name}_{seed}.log_std"] = mean, log_std
            expected[f"{name}_{seed}.q"] = nets.critic(task_in, robot_in, action)
    stitched, sig = stitch_policies(paths[0], paths[1])
    with torch.no_grad():
        expected[f"{name}_stitched.mean"] = stitched.actor(task_in, robot_in)[0]
        expected[f"{name}_stitched.q"] = stitched.critic(task_in, robot_in, action)
save_file({k: v.contiguous() for k, v in expected.items()}, f"{out}/expected.safetensors", metadata={"written_by": "ps_ray d6cafd7"})
print(len(METHODS), "methods")
