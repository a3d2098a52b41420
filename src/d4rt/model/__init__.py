"""The D4RT network: pure ``nn.Module``s (no file or video I/O) plus the encoded-scene query layer.

    layers           attention (SDPA), MLP, transformer block, sine-cosine and Fourier encodings
    encoder          tubelet embedding, space-time positions, frame-local / global ViT, aspect token
    query_embedding  Fourier (u, v) + three time embeddings + bilinear RGB patch
    decoder          cross-attention + MLP blocks (no query-query attention) and the prediction heads
    inputs           input checks (UserError on bad input), resizing, tubelet padding
    scene            EncodedScene: chunked, KV-cached query decoding of one encoded clip
    d4rt             the D4RT module: encode, batched training forward, save / load
    weights          safetensors + config.json checkpoints with strict key checking
    videomae         VideoMAE v2 checkpoint -> encoder weights
"""

from d4rt.config import D4RTConfig
from d4rt.model.d4rt import D4RT
from d4rt.model.encoded_scene import EncodedScene

__all__ = ["D4RT", "D4RTConfig", "EncodedScene"]
