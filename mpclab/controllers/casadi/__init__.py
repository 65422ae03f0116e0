"""The CasADi family: the OCP as a nonlinear program (`ocp`), solved by IPOPT, fatrop, SQP or
Uno (`mpc`, `solvers`, `uno`), its compiled functions (`compile`) and generated C (`codegen`),
the initial guess (`guess`), time-capped solves (`time_cap`) and the real-time iteration
(`rti`)."""
