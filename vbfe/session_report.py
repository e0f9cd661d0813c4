def write_session_report(*a): raise NotImplementedError
