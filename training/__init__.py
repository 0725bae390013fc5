"""nkrr network-prior training pipeline (see training/README section in docs/network.md)."""
import os

# Under CPU oversubscription (other builds on the same 2 cores) OpenMP's default spin-waiting makes
# PyTorch several times slower; passive waiting keeps it near single-thread speed at worst.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
