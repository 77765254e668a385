"""Task supervisors: the paper's manipulation tasks as small state machines.

``supervisor.handover`` and ``supervisor.stacking`` (task 3: shear-based handover and
blind stacking), ``supervisor.sort`` and ``supervisor.dish_loading`` (task 1: dish
loading with recycling separation), ``supervisor.antagonism`` (task 2: pose tracking
under antagonism). ``base`` holds what they share (the data clock and the verdict).
"""
