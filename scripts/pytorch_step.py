"""A nerf-pytorch-style paper training step on the CPU, for `nerf bench`'s comparison.

Not part of the project or CI (it needs PyTorch, which the project does not install). It times
the reference recipe the way nerf-pytorch runs it: 1024 rays, 64 stratified (perturbed) + 128
importance samples, two 8×256 networks with the skip after the 5th layer and view directions,
positional encoding L=10 / L=4, network queries in chunks of 65,536 points (`netchunk`), MSE on
coarse + fine, Adam (lr 5e-4). Prints forward / backward / update seconds and peak RSS.

    python scripts/pytorch_step.py [--steps 5] [--threads 2] [--json FILE]
"""

import argparse
import json
import resource
import time

import torch
import torch.nn as nn
import torch.nn.functional as F


def embed(x, n_freqs):
    """[x, sin(2^k x), cos(2^k x)] for k < n_freqs (nerf-pytorch's Embedder, log sampling)."""
    out = [x]
    for k in range(n_freqs):
        f = 2.0**k
        out += [torch.sin(x * f), torch.cos(x * f)]
    return torch.cat(out, -1)


class NeRF(nn.Module):
    """nerf-pytorch's NeRF (D=8, W=256, skips=[4], use_viewdirs=True)."""

    def __init__(self, depth=8, width=256, in_pts=63, in_views=27, skips=(4,)):
        super().__init__()
        self.skips = skips
        self.pts_linears = nn.ModuleList(
            [nn.Linear(in_pts, width)]
            + [nn.Linear(width + in_pts if i in skips else width, width) for i in range(depth - 1)]
        )
        self.views_linears = nn.ModuleList([nn.Linear(in_views + width, width // 2)])
        self.feature_linear = nn.Linear(width, width)
        self.alpha_linear = nn.Linear(width, 1)
        self.rgb_linear = nn.Linear(width // 2, 3)
        self.in_pts = in_pts

    def forward(self, x):
        pts, views = torch.split(x, [self.in_pts, x.shape[-1] - self.in_pts], dim=-1)
        h = pts
        for i, layer in enumerate(self.pts_linears):
            h = F.relu(layer(h))
            if i in self.skips:
                h = torch.cat([pts, h], -1)
        alpha = self.alpha_linear(h)
        h = torch.cat([self.feature_linear(h), views], -1)
        for layer in self.views_linears:
            h = F.relu(layer(h))
        return torch.cat([self.rgb_linear(h), alpha], -1)


def run_network(pts, viewdirs, net, netchunk=1024 * 64):
    flat = pts.reshape(-1, 3)
    dirs = viewdirs[:, None].expand(pts.shape).reshape(-1, 3)
    x = torch.cat([embed(flat, 10), embed(dirs, 4)], -1)
    out = torch.cat([net(x[i : i + netchunk]) for i in range(0, x.shape[0], netchunk)], 0)
    return out.reshape(list(pts.shape[:-1]) + [4])


def raw2outputs(raw, z_vals, rays_d):
    dists = z_vals[..., 1:] - z_vals[..., :-1]
    dists = torch.cat([dists, torch.full_like(dists[..., :1], 1e10)], -1)
    dists = dists * torch.norm(rays_d[..., None, :], dim=-1)
    rgb = torch.sigmoid(raw[..., :3])
    alpha = 1.0 - torch.exp(-F.relu(raw[..., 3]) * dists)
    trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha + 1e-10], -1), -1)[:, :-1]
    weights = alpha * trans
    rgb_map = torch.sum(weights[..., None] * rgb, -2)
    acc = torch.sum(weights, -1)
    return rgb_map + (1.0 - acc[..., None]), weights


def sample_pdf(bins, weights, n_samples):
    weights = weights + 1e-5
    pdf = weights / torch.sum(weights, -1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[..., :1]), torch.cumsum(pdf, -1)], -1)
    u = torch.rand(list(cdf.shape[:-1]) + [n_samples]).contiguous()
    inds = torch.searchsorted(cdf, u, right=True)
    below = torch.clamp(inds - 1, min=0)
    above = torch.clamp(inds, max=cdf.shape[-1] - 1)
    g = torch.stack([below, above], -1)
    shape = [g.shape[0], g.shape[1], cdf.shape[-1]]
    cdf_g = torch.gather(cdf.unsqueeze(1).expand(shape), 2, g)
    bins_g = torch.gather(bins.unsqueeze(1).expand(shape), 2, g)
    denom = cdf_g[..., 1] - cdf_g[..., 0]
    denom = torch.where(denom < 1e-5, torch.ones_like(denom), denom)
    t = (u - cdf_g[..., 0]) / denom
    return bins_g[..., 0] + t * (bins_g[..., 1] - bins_g[..., 0])


def render_rays(rays_o, rays_d, coarse, fine, near=2.0, far=6.0, n_coarse=64, n_fine=128):
    viewdirs = rays_d / torch.norm(rays_d, dim=-1, keepdim=True)
    t = torch.linspace(0.0, 1.0, n_coarse)
    z = (near * (1.0 - t) + far * t).expand(rays_o.shape[0], n_coarse)
    mids = 0.5 * (z[..., 1:] + z[..., :-1])
    upper = torch.cat([mids, z[..., -1:]], -1)
    lower = torch.cat([z[..., :1], mids], -1)
    z = lower + (upper - lower) * torch.rand(z.shape)
    pts = rays_o[..., None, :] + rays_d[..., None, :] * z[..., :, None]
    rgb0, weights = raw2outputs(run_network(pts, viewdirs, coarse), z, rays_d)
    mids = 0.5 * (z[..., 1:] + z[..., :-1])
    z_fine = sample_pdf(mids, weights[..., 1:-1], n_fine).detach()
    z_all, _ = torch.sort(torch.cat([z, z_fine], -1), -1)
    pts = rays_o[..., None, :] + rays_d[..., None, :] * z_all[..., :, None]
    rgb, _ = raw2outputs(run_network(pts, viewdirs, fine), z_all, rays_d)
    return rgb0, rgb


def random_rays(n, focal=138.9, size=100):
    """Rays of a camera 4 units from the origin looking at it (the lego cameras' setting)."""
    i = torch.randint(0, size, (n,)).float()
    j = torch.randint(0, size, (n,)).float()
    d = torch.stack([(i - size / 2) / focal, -(j - size / 2) / focal, -torch.ones(n)], -1)
    return torch.tensor([0.0, 0.0, 4.0]).expand(n, 3), d


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    coarse, fine = NeRF(), NeRF()
    optim = torch.optim.Adam(list(coarse.parameters()) + list(fine.parameters()), lr=5e-4, betas=(0.9, 0.999))
    times = []
    for step in range(args.warmup + args.steps):
        rays_o, rays_d = random_rays(1024)
        target = torch.rand(1024, 3)
        t0 = time.perf_counter()
        rgb0, rgb = render_rays(rays_o, rays_d, coarse, fine)
        loss = F.mse_loss(rgb0, target) + F.mse_loss(rgb, target)
        loss.item()
        t1 = time.perf_counter()
        optim.zero_grad()
        loss.backward()
        t2 = time.perf_counter()
        optim.step()
        t3 = time.perf_counter()
        if step >= args.warmup:
            times.append((t3 - t0, t1 - t0, t2 - t1, t3 - t2))
    mean = [sum(col) / len(col) for col in zip(*times)]
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    result = {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "steps": args.steps,
        "step_s": mean[0],
        "forward_s": mean[1],
        "backward_s": mean[2],
        "update_s": mean[3],
        "peak_rss_mb": peak_mb,
    }
    print(f"pytorch {torch.__version__} ({result['threads']} threads), paper step, mean of {args.steps} after {args.warmup} warm-up")
    print(f"step {mean[0]:.3f} s  forward {mean[1]:.3f}  backward {mean[2]:.3f}  update {mean[3]:.3f}  peak RSS {peak_mb:.0f} MB")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
