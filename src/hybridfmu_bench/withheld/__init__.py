"""The withheld-effect check of the diagnosis, on the emulated bench: cases whose bench has an effect the FMU
lacks (:mod:`.suite`: drawing, emulating, ingesting, diagnosing each case), scored against the bench's ground
truth (:mod:`.scoring`) and aggregated (:mod:`.report`).

It sits beside the diagnosis, not in it: the suite drives the bench and reads its truth to score, while
:mod:`hybridfmu.diagnosis` never imports the bench.
"""
