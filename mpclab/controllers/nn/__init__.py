"""The net: a trained MLP imitating an MPC law, as a controller (`controller`)."""
