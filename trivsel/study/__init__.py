"""Studies of the method, apart from the library: the reproduction of Table 1 and
Figs. 4-6 (:mod:`.report`, :mod:`.figures`, :mod:`.published`), the ablation of
the paper's open choices (:mod:`.ablation`), the comparison of methods at matched
vertex counts (:mod:`.comparison`) with its baselines such as VTK's quadric
decimation (:mod:`.baselines`), time and memory against size (:mod:`.scaling`), and
trivsel against VTK on real volumes (:mod:`.realdata`).

They need the ``study`` extra (matplotlib, pyvista/VTK, pandas, snakemake for the
workflow); ``import trivsel`` never imports them.
"""
