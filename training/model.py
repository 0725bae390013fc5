"""ConvONet-lite, exactly as docs/network.md specifies (triplane variant).

state_dict names are the tensor names of assets/prior.safetensors.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn as nn
import torch.nn.functional as Fn

PLANES = ((0, 2), (0, 1), (1, 2))  # xz, xy, yz: (a, b) -> u = p[a], v = p[b]
N_BLOCKS_ENC = 5


@dataclass
class Config:
    h: int = 32
    c_dim: int = 32
    reso: int = 64
    unet_depth: int = 3
    unet_filters: int = 32
    h_dec: int = 32
    n_blocks_dec: int = 5
    padding: float = 0.1

    def to_dict(self):
        return asdict(self)


class ResBlock(nn.Module):
    def __init__(self, i, o):
        super().__init__()
        hh = min(i, o)
        self.fc_0 = nn.Linear(i, hh)
        self.fc_1 = nn.Linear(hh, o)
        self.shortcut = nn.Linear(i, o, bias=False) if i != o else None
        nn.init.zeros_(self.fc_1.weight)  # ConvONet init; not part of the contract

    def forward(self, x):
        dx = self.fc_1(torch.relu(self.fc_0(torch.relu(x))))
        xs = self.shortcut(x) if self.shortcut is not None else x
        return xs + dx


def plane_uv(p, padding):
    """p: (..., 3) -> (..., 3 planes, 2) with u, v in [0, 1 - 1e-5]."""
    uv = torch.stack([p[..., [a, b]] for a, b in PLANES], dim=-2)
    return torch.clamp(uv / (1 + padding) + 0.5, 0.0, 1 - 1e-5)


def cell_index(uv, reso):
    """uv: (B, N, 3, 2) -> flat cell index iy*R + ix, (B, N, 3) int64."""
    ij = torch.floor(uv * reso).long()
    return ij[..., 1] * reso + ij[..., 0]


class Encoder(nn.Module):
    def __init__(self, cfg: Config):
        super().__init__()
        self.cfg = cfg
        h = cfg.h
        self.fc_pos = nn.Linear(3, 2 * h)
        self.blocks = nn.ModuleList([ResBlock(2 * h, h) for _ in range(N_BLOCKS_ENC)])
        self.fc_c = nn.Linear(h, cfg.c_dim)

    def forward(self, p):
        """p: (B, N, 3) normalised cloud -> planes (B, 3, c_dim, R, R) before the U-Net."""
        B, N, _ = p.shape
        R = self.cfg.reso
        idx = cell_index(plane_uv(p, self.cfg.padding), R)  # (B, N, 3)
        # global index over (batch, plane, cell)
        off = (torch.arange(B, device=p.device)[:, None, None] * 3 + torch.arange(3, device=p.device)) * (R * R)
        gidx = (idx + off).reshape(B, N * 3)  # point-major: [n0p0, n0p1, n0p2, n1p0, ...]
        gflat = gidx.reshape(-1)
        net = self.blocks[0](self.fc_pos(p))
        for blk in self.blocks[1:]:
            C = net.shape[-1]
            src = net.unsqueeze(2).expand(B, N, 3, C).reshape(-1, C)
            pool = net.new_zeros(B * 3 * R * R, C)
            pool = pool.scatter_reduce(0, gflat[:, None].expand(-1, C), src, "amax", include_self=False)
            pooled = pool[gflat].reshape(B, N, 3, C).sum(2)
            net = blk(torch.cat([net, pooled], dim=-1))
        c = self.fc_c(net)  # (B, N, c_dim)
        C = c.shape[-1]
        src = c.unsqueeze(2).expand(B, N, 3, C).reshape(-1, C)
        planes = c.new_zeros(B * 3 * R * R, C)
        planes = planes.scatter_reduce(0, gflat[:, None].expand(-1, C), src, "mean", include_self=False)
        return planes.reshape(B, 3, R, R, C).permute(0, 1, 4, 2, 3).contiguous()


class UpLevel(nn.Module):
    def __init__(self, fin, fout):
        super().__init__()
        self.upconv = nn.ConvTranspose2d(fin, fout, 2, stride=2)
        self.conv0 = nn.Conv2d(2 * fout, fout, 3, padding=1)
        self.conv1 = nn.Conv2d(fout, fout, 3, padding=1)


class DownLevel(nn.Module):
    def __init__(self, fin, fout):
        super().__init__()
        self.conv0 = nn.Conv2d(fin, fout, 3, padding=1)
        self.conv1 = nn.Conv2d(fout, fout, 3, padding=1)


class UNet(nn.Module):
    def __init__(self, cfg: Config):
        super().__init__()
        D, f = cfg.unet_depth, cfg.unet_filters
        fs = [f * 2 ** k for k in range(D)]
        self.down = nn.ModuleList([DownLevel(cfg.c_dim if k == 0 else fs[k - 1], fs[k]) for k in range(D)])
        # up[k] produces level k from level k+1, k = 0..D-2
        self.up = nn.ModuleList([UpLevel(fs[k + 1], fs[k]) for k in range(D - 1)])
        self.final = nn.Conv2d(f, cfg.c_dim, 1)

    def forward(self, x):
        skips = []
        for k, lv in enumerate(self.down):
            if k > 0:
                x = Fn.max_pool2d(x, 2, 2)
            x = torch.relu(lv.conv1(torch.relu(lv.conv0(x))))
            skips.append(x)
        for k in range(len(self.up) - 1, -1, -1):
            lv = self.up[k]
            x = lv.upconv(x)
            x = torch.cat([x, skips[k]], dim=1)
            x = torch.relu(lv.conv1(torch.relu(lv.conv0(x))))
        return self.final(x)


def sample_planes(planes, q, padding):
    """Bilinear, align-corners, border-clamped. planes (B, 3, C, R, R), q (B, Q, 3) -> (B, Q, C)."""
    B, _, C, R, _ = planes.shape
    uv = plane_uv(q, padding) * (R - 1)  # (B, Q, 3, 2), x = u, y = v
    x, y = uv[..., 0], uv[..., 1]
    x0f, y0f = torch.floor(x), torch.floor(y)
    wx, wy = (x - x0f).unsqueeze(-1), (y - y0f).unsqueeze(-1)
    x0, y0 = x0f.long(), y0f.long()
    x1, y1 = torch.clamp(x0 + 1, max=R - 1), torch.clamp(y0 + 1, max=R - 1)
    flat = planes.permute(0, 1, 3, 4, 2).reshape(B, 3 * R * R, C)
    poff = torch.arange(3, device=q.device) * (R * R)

    def g(yy, xx):
        i = (yy * R + xx + poff).reshape(B, -1, 1).expand(-1, -1, C)
        return torch.gather(flat, 1, i).reshape(B, -1, 3, C)

    f = (g(y0, x0) * (1 - wx) * (1 - wy) + g(y0, x1) * wx * (1 - wy)
         + g(y1, x0) * (1 - wx) * wy + g(y1, x1) * wx * wy)
    return f.sum(2)


class Decoder(nn.Module):
    def __init__(self, cfg: Config):
        super().__init__()
        self.fc_p = nn.Linear(3, cfg.h_dec)
        self.fc_c = nn.ModuleList([nn.Linear(cfg.c_dim, cfg.h_dec) for _ in range(cfg.n_blocks_dec)])
        self.blocks = nn.ModuleList([ResBlock(cfg.h_dec, cfg.h_dec) for _ in range(cfg.n_blocks_dec)])
        self.fc_out = nn.Linear(cfg.h_dec, 1)

    def forward(self, q, feat):
        net = self.fc_p(q)
        for fc, blk in zip(self.fc_c, self.blocks):
            net = blk(net + fc(feat))
        return self.fc_out(torch.relu(net)).squeeze(-1)


class ConvONet(nn.Module):
    def __init__(self, cfg: Config | None = None):
        super().__init__()
        self.cfg = cfg or Config()
        R, D = self.cfg.reso, self.cfg.unet_depth
        assert R % (2 ** (D - 1)) == 0, "reso must be divisible by 2^(unet_depth-1)"
        self.encoder = Encoder(self.cfg)
        self.unet = UNet(self.cfg)
        self.decoder = Decoder(self.cfg)

    def encode(self, p):
        """p (B, N, 3) -> planes (B, 3, c_dim, R, R) after the U-Net."""
        pl = self.encoder(p)
        B, P, C, R, _ = pl.shape
        return self.unet(pl.reshape(B * P, C, R, R)).reshape(B, P, C, R, R)

    def features(self, planes, q):
        return sample_planes(planes, q, self.cfg.padding)

    def decode(self, planes, q):
        return self.decoder(q, self.features(planes, q))

    def forward(self, p, q):
        return self.decode(self.encode(p), q)
