"""Frames and benchmark configurations on a Dask cluster (``--workers N``, ``--scheduler ADDRESS``).

Frames are independent, so a sequence spreads over processes and machines perfectly; the cluster
is Dask's ``distributed`` scheduler (an optional extra: ``pip install 'gridrt[cluster]'``): a local
cluster of worker processes started here (``--workers N``), or an existing one (``dask scheduler``
and ``dask worker`` processes anywhere, ``--scheduler tcp://HOST:PORT``).  Without either flag
Dask is not imported.

A dump is cut into chunks of consecutive frames.  Each worker process loads the scene once and
keeps it, with its pipeline (kernels warmed, grids and buffers allocated), for its next chunks;
it renders a chunk, encodes the PNGs (and the ``.npy`` buffers) and sends the bytes back.  The
client writes every file itself: the workers need no folder in common with it (a cluster of
machines seldom has one), the output folder is written by one process only, and a frame is
written only once, whatever the retries.  The files are written in frame order, each PNG and
buffer whole (written under a temporary name, then renamed), and then its row of ``stats.csv``.

A pipeline carries state from frame to frame: the frame of reference the scene is gridded in
(chosen at the first frame, moved when the scene drifts far), the camera that frames the scene at
the first frame, and a static scene's grid.  A worker that starts a chunk in the middle takes that
state with :meth:`gridrt.pipeline.FramePipeline.resume`: the first frame's camera and origin (it
places the first frame itself, without rendering it), and the origin the previous chunk ended
with when the client knows it.  A chunk whose start differs from where its predecessor ended (the
scene moved its frame in between: rare) is rendered again from there; so the output is that of a
one-process dump, bit for bit.

Faults: a worker that dies loses its chunks to Dask, which runs them again on the other workers
(chunks are pure: same input, same bytes).  A task's error (a scene that does not load, say) is
raised once, on the client, and stops the run.
"""
