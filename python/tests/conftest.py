import os

import pytest

# Two cores are shared on CI machines: one torch thread keeps SB3 tests from fighting the
# simulation for them.
os.environ.setdefault("OMP_NUM_THREADS", "1")


@pytest.fixture(autouse=True, scope="session")
def _torch_threads():
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    yield
