"""The scheduled family (Study C): linear models at operating points (`models`, `grid`), their
condensed QPs (`dense_qp`), the switched, interpolated and adaptive controller (`mpc`) and its
generated C in the loop (`generated_c`)."""
