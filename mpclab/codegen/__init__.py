"""Generated C for controllers: emitters, the desktop compile cache, and the Cortex-M4 PIL.

This package sits below :mod:`mpclab.controllers`: controllers import it, it imports no
controller. Its emitters take plain arrays (the matrices a controller precomputed at build
time) and return C source; :mod:`mpclab.codegen.build` compiles C into cached shared objects.
"""
