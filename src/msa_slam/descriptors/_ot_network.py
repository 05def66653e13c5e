"""OverlapTransformer network (Ma et al., RA-L 2022) at inference, laid out so the authors' weights load.

Imports torch at module level: only import this through `overlap_transformer.load_network`.
Layer facts: docs/descriptors.md, "OverlapTransformer".
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

# (in, out, kernel height, stride height) of conv1..conv11; all bias-free, ReLU after each.
_CONVS = [(1, 16, 5, 1), (16, 32, 3, 2), (32, 64, 3, 2), (64, 64, 3, 2), (64, 128, 2, 2)] + [(128, 128, 1, 2)] * 6


class NetVLADLoupe(nn.Module):
    """NetVLAD with context gating ("Loupe" form, Miech et al. 2017), no batch norm."""

    def __init__(self, feature_size: int = 1024, cluster_size: int = 64, output_dim: int = 256) -> None:
        super().__init__()
        self.cluster_weights = nn.Parameter(torch.empty(feature_size, cluster_size))
        self.cluster_weights2 = nn.Parameter(torch.empty(1, feature_size, cluster_size))
        self.hidden1_weights = nn.Parameter(torch.empty(cluster_size * feature_size, output_dim))
        self.cluster_biases = nn.Parameter(torch.empty(cluster_size))
        self.context_gating = ContextGating(output_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # x: (B, samples, features)
        assign = torch.softmax(x @ self.cluster_weights + self.cluster_biases, dim=-1)
        residual_mass = assign.sum(dim=-2, keepdim=True) * self.cluster_weights2  # (B, F, K)
        vlad = (assign.transpose(2, 1) @ x).transpose(2, 1) - residual_mass
        vlad = F.normalize(vlad, dim=1).reshape(x.shape[0], -1)
        return self.context_gating(F.normalize(vlad, dim=1) @ self.hidden1_weights)


class ContextGating(nn.Module):
    """y * sigmoid(y W + b)."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.gating_weights = nn.Parameter(torch.empty(dim, dim))
        self.gating_biases = nn.Parameter(torch.empty(dim))

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        return y * torch.sigmoid(y @ self.gating_weights + self.gating_biases)


class OverlapTransformerNet(nn.Module):
    """Range image (B, 1, 64, 900) -> L2-normalised yaw-invariant descriptor (B, 256)."""

    def __init__(self) -> None:
        super().__init__()
        for i, (c_in, c_out, k, s) in enumerate(_CONVS, start=1):
            setattr(self, f"conv{i}", nn.Conv2d(c_in, c_out, (k, 1), stride=(s, 1), bias=False))
        self.convLast1 = nn.Conv2d(128, 256, 1, bias=False)
        self.convLast2 = nn.Conv2d(512, 1024, 1, bias=False)
        layer = nn.TransformerEncoderLayer(
            d_model=256, nhead=4, dim_feedforward=1024, activation="relu", batch_first=False, dropout=0.0
        )
        self.transformer_encoder = nn.TransformerEncoder(layer, num_layers=1, enable_nested_tensor=False)
        self.net_vlad = NetVLADLoupe()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for i in range(1, len(_CONVS) + 1):
            x = F.relu(getattr(self, f"conv{i}")(x))
        f1 = F.relu(self.convLast1(x.permute(0, 1, 3, 2)))  # (B, 256, 900, 1)
        seq = f1.squeeze(3).permute(2, 0, 1)  # (900, B, 256)
        f2 = self.transformer_encoder(seq).permute(1, 2, 0).unsqueeze(3)
        feat = F.normalize(F.relu(self.convLast2(torch.cat((f1, f2), dim=1))), dim=1)  # (B, 1024, 900, 1)
        samples = feat.squeeze(3).transpose(1, 2)  # (B, 900, 1024)
        return F.normalize(self.net_vlad(samples), dim=1)
