"""The NN policy at run time: its input features and the network with its file format.

What ``controller=nn`` needs to drive a plant, below the controllers; the training
application that makes the network (dataset, training, DAgger, evaluation, C export) is
``mpclab.approx``, above the runner.
"""
