"""The CVXPY family: successive linearization (`successive_linearization`) of the OCP into QPs
built once (`mpc`), handed straight to a persistent solver (`direct`), with the objective's
constraints linearized (`constraints`)."""
