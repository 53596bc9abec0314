"""Wall time of the sympy derivation check (poiseuille.derivation.check): every Hessian entry and constant."""
import time

from poiseuille import derivation

t0 = time.perf_counter()
checks = derivation.check()
elapsed = time.perf_counter() - t0
failed = [c.name for c in checks if c.kind == "derivation" and not c.ok]
print(f"{len(checks)} checks, {len(failed)} failed, {elapsed:.1f} s")
