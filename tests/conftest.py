import pytest
import torch


@pytest.fixture
def one_torch_thread():
    """One intra-op thread: small tensors gain nothing from more, and on a shared CPU OpenMP
    threads waiting for each other slow every op down by orders of magnitude."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
