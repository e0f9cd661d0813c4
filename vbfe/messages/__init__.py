"""ROS 2 messages as vbfe publishes them: topics, schemas and frame ids (``topics``), message
builders (``builders``) and image codecs (``images``); shared by the MCAP export
(:mod:`vbfe.bags`) and the live Foxglove server (:mod:`vbfe.live`), below both."""
