"""studyctl.scenes"""
