"""Transformer-S2A, its MoE layer and the baselines: shapes, masking, routing, learning."""

import pytest
import torch

from train import BLSTM, NVP, BLSTMConfig, MoELayer, NVPConfig, S2AConfig, TransformerS2A, masked_mse
from train.moe import expert_loop_reference
from train.precision import bf16_is_native, for_inference, infer

SMALL = dict(d_model=32, heads=2, encoder_layers=1, decoder_layers=1, ff_dim=64, expert_hidden=8, dropout=0.0)


def models():
    return {
        "s2a": TransformerS2A(S2AConfig(**SMALL)),
        "s2a-nomoe": TransformerS2A(S2AConfig(**SMALL, moe=False)),
        "s2a-noprosody": TransformerS2A(S2AConfig(**SMALL, prosody_dim=0)),
        "blstm": BLSTM(BLSTMConfig(hidden=16, layers=2, dropout=0.0)),
        "nvp3": NVP(NVPConfig(window=3, hidden=32, dropout=0.0)),
        "nvp9": NVP(NVPConfig(window=9, hidden=32, dropout=0.0)),
    }


@pytest.mark.parametrize("name", sorted(models()))
def test_shapes_and_padding_does_not_leak(name):
    torch.manual_seed(0)
    model = models()[name].eval()
    prosody_dim = model.config.prosody_dim
    content = torch.randn(2, 40, 64)
    prosody = torch.randn(2, 40, prosody_dim) if prosody_dim else None
    mask = torch.ones(2, 40, dtype=torch.bool)
    mask[1, 25:] = False
    with torch.no_grad():
        out = model(content, prosody, mask)
        assert out.shape == (2, 40, 32)
        # The padded sequence's real frames equal the same sequence run alone, unpadded.
        alone = model(content[1:, :25], prosody[1:, :25] if prosody is not None else None, mask[1:, :25])
        # Garbage in the padding changes nothing either.
        content2 = content.clone()
        content2[1, 25:] = 1e3
        again = model(content2, prosody, mask)
    assert torch.allclose(out[1, :25], alone[0], atol=1e-5)
    assert torch.allclose(out[1, :25], again[1, :25], atol=1e-5)


def test_dense_sparse_grouped_routed_and_loop_agree():
    torch.manual_seed(1)
    layer = MoELayer(24, 8, experts=12, top_k=4, kernel_size=3, inference="train").eval()
    h = torch.randn(3, 30, 24)
    with torch.no_grad():
        dense = layer(h)
        layer.mode = "sparse"
        sparse = layer(h)
        layer.mode = "grouped"
        grouped = layer(h)
        loop = expert_loop_reference(layer, h)
        layer.inference = "routed"  # the inference path (eval, no autograd)
        routed = layer(h)
    assert not torch.equal(routed, dense)  # a different computation...
    for other in (sparse, grouped, loop, routed):
        assert torch.allclose(dense, other, atol=1e-5)  # ...of the same numbers


@pytest.mark.parametrize("kernel", [1, 3, 5])
def test_routed_inference_path_matches_training_path_in_the_model(kernel):
    torch.manual_seed(6)
    model = TransformerS2A(S2AConfig(**SMALL, experts=10, top_k=3, expert_kernel=kernel)).eval()
    content, prosody = torch.randn(3, 37, 64), torch.randn(3, 37, 3)
    mask = torch.ones(3, 37, dtype=torch.bool)
    mask[1, 20:] = False
    layers = [m for m in model.modules() if isinstance(m, MoELayer)]
    with torch.inference_mode():
        fast = model(content, prosody, mask)
        for m in layers:
            m.inference = "train"
        slow = model(content, prosody, mask)
        for m in layers:
            m.inference = "routed"
    assert torch.allclose(fast[mask], slow[mask], atol=1e-5)
    # the cached expert weights follow an in-place update (an optimizer step)
    with torch.no_grad():
        for m in layers:
            m.conv.weight.mul_(1.5)
        fast2 = model(content, prosody, mask)
        for m in layers:
            m.inference = "train"
        slow2 = model(content, prosody, mask)
    assert torch.allclose(fast2[mask], slow2[mask], atol=1e-5)
    assert not torch.allclose(fast2[mask], fast[mask], atol=1e-3)
    # in training mode (or with autograd) the routed path is never taken: gradients flow as usual
    model.train()
    assert model(content, prosody, mask).requires_grad


@pytest.mark.skipif(not bf16_is_native(), reason="no native bfloat16 on this CPU")
def test_bf16_inference_follows_fp32_on_every_path():
    """The bfloat16 copy runs the routed MoE path (rows padded to 16 bytes = 8 bfloat16 values; d_model
    30 needs the padding) and stays within bfloat16 rounding of the float32 model."""
    torch.manual_seed(7)
    model = TransformerS2A(S2AConfig(**{**SMALL, "d_model": 30}, experts=10, top_k=3)).eval()
    content, prosody = torch.randn(2, 50, 64), torch.randn(2, 50, 3)
    mask = torch.ones(2, 50, dtype=torch.bool)
    half = for_inference(model, "bf16")
    assert next(model.parameters()).dtype == torch.float32  # a copy: the original is untouched
    layers = [m for m in half.modules() if isinstance(m, MoELayer)]
    with torch.inference_mode():
        exact = infer(model, content, prosody, mask)
        fast = infer(half, content, prosody, mask)
        for m in layers:
            m.inference = "train"
        slow = infer(half, content, prosody, mask)
    assert fast.dtype == torch.float32
    scale = float(exact.abs().max())
    assert float((fast - exact).abs().max()) < 0.05 * scale
    assert float((fast - slow).abs().max()) < 0.05 * scale
    assert not torch.equal(fast, exact)  # it really ran in bfloat16


@pytest.mark.parametrize("d_model", [24, 30])  # 30: rows the grouped product cannot take (sparse instead)
def test_every_training_path_runs_under_bf16_autocast(d_model):
    """amp = "bf16" on CPU: each MoE mode trains and stays near its float32 result."""
    for mode in ("dense", "sparse", "grouped"):
        torch.manual_seed(4)
        layer = MoELayer(d_model, 8, experts=6, top_k=2, mode=mode)
        h = torch.randn(2, 20, d_model, requires_grad=True)
        exact = layer(h)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = layer(h)
        out.float().square().mean().backward()
        assert h.grad is not None and torch.isfinite(h.grad).all()
        diff, scale = (out.float() - exact).abs().max().item(), exact.abs().max().item()
        assert diff < 0.05 * scale, mode


def test_gradients_agree_between_paths():
    torch.manual_seed(2)
    grads = {}
    for mode in ("dense", "sparse", "grouped"):
        torch.manual_seed(3)
        layer = MoELayer(16, 8, experts=6, top_k=2, mode=mode)
        h = torch.randn(2, 20, 16, requires_grad=True)
        layer(h).square().sum().backward()
        grads[mode] = (h.grad, layer.conv.weight.grad, layer.linear_weight.grad, layer.gate.weight.grad)
    for other in ("sparse", "grouped"):
        for a, b in zip(grads["dense"], grads[other]):
            assert torch.allclose(a, b, atol=1e-4)


def test_top_k_keeps_exactly_k_experts_with_softmax_weights():
    torch.manual_seed(4)
    layer = MoELayer(16, 4, experts=48, top_k=16).eval()
    idx, probs = layer.route(torch.randn(2, 10, 16))
    assert idx.shape == (2, 10, 16) and probs.shape == (2, 10, 16)
    assert all(len(set(row.tolist())) == 16 for row in idx.reshape(-1, 16))
    assert torch.allclose(probs.sum(-1), torch.ones(2, 10))
    scores = layer.gate(torch.randn(1, 1, 16))
    kept = scores.topk(16, dim=-1).values
    assert torch.all(kept.min() >= scores.sort(dim=-1, descending=True).values[..., 16])


def test_load_balancing_loss_is_reported_in_training():
    layer = MoELayer(16, 4, experts=8, top_k=2).train()
    layer(torch.randn(2, 10, 16))
    assert layer.aux_loss.item() > 0
    assert MoELayer(16, 4, experts=4, top_k=4).train()(torch.randn(1, 3, 16)).shape == (1, 3, 16)


def test_paper_defaults():
    c = S2AConfig()
    assert (c.experts, c.top_k, c.content_dim, c.out_dim) == (48, 16, 64, 32)
    with pytest.raises(ValueError):
        MoELayer(16, 4, experts=4, top_k=5)


@pytest.mark.parametrize("name", ["s2a", "blstm", "nvp9"])
def test_a_tiny_model_overfits_a_tiny_dataset(name):
    torch.manual_seed(5)
    model = models()[name].train()
    content = torch.randn(4, 30, 64)
    prosody = torch.randn(4, 30, 3)
    mask = torch.ones(4, 30, dtype=torch.bool)
    target = torch.tanh(content[..., :32] + content.roll(1, dims=1)[..., 32:]) * 0.5
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    first = None
    for _ in range(250):
        loss = masked_mse(model(content, prosody, mask), target, mask)
        if first is None:
            first = loss.item()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < first / 10
