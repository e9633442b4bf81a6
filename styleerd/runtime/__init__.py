"""What users run, without torch: the per-frame stylizer (StreamStylizer on the model's skeleton,
ChannelStylizer on the user's), its backends, foot cleanup, file transfer (one file, many, FBX
through Blender) and the ONNX export."""
