"""PUMA: learned stable second-order motion primitives on R³ × S³ (and Rⁿ), in minutes on a CPU.

Modules (data flows down the list):

- ``manifold``: unit quaternions, the S³ exponential/logarithm maps and tangent spaces;
- ``data``: restricted-unpickler loader of the authors' ``ee_state_*.pk``, LASA loader,
  preparation (goal-relative, resampled to Δt, velocities consistent with the integrator);
- ``demos_synthetic``: seeded tomato/pouring demonstrations (offline default);
- ``network`` (ρ, φ, normalisation, ψ), ``dynamics`` (semi-implicit Euler with the exponential map),
  ``losses`` (imitation, triplet stability, ψ-compatibility, boundary), ``training``;
- ``evaluation`` (RMSE, DTW, Fréchet; convergence from random starts; ψ-compatibility),
  ``checkpoint`` (strict save/load), ``pipeline`` (config → checkpoint + report),
  ``lasa_benchmark``;
- ``primitive``: ``load_primitive(path)`` → ``PosePrimitive`` / ``VectorPrimitive`` for the
  controllers (numpy in/out, world frame, physical units), evaluated by ``fastnet``.

torch is imported only inside this package (and by ``tamedpuma.train``).
"""
